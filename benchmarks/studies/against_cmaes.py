"""A Table 4 rule's runs against CMA-ES on all of them (the bar "within 2x of CMA-ES": at most 2x CMA-ES's
mean distance).

The default run pairs Table 4's 60 runs per level with Table 3's CMA-ES on runs 0..baselines.runs-1 (20, for
the time budget). This runs CMA-ES (the default run's tuned settings) on every run a rule's files hold and
prints both means per level and their ratio, measured in one run:

    PYTHONPATH=src python benchmarks/studies/against_cmaes.py results/sky/sky.bin results/split/split.json \\
        results/baselines/tuning_cmaes.csv 'results/research/rules/closed_centred_r1_then_group_crossing_x4_level*.csv'
"""
from __future__ import annotations

import argparse
import glob
import json
import sys
import time

import pandas as pd
import torch

from sdm.experiments.baselines import baseline_noise_runs, best_settings
from sdm.experiments import load_split
from sdm.experiments.report.research import CMAES_FACTOR


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sky")
    parser.add_argument("split")
    parser.add_argument("tuning", help="the default run's results/baselines/tuning_cmaes.csv (its dev loss picks)")
    parser.add_argument("rule_files", help="a glob of one rule's Table 4 files, one per level")
    parser.add_argument("--seed", type=int, default=0, help="noise.seed of the run that wrote the files")
    parser.add_argument("--csv", help="write CMA-ES's per-run rows here")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    train_set, _, camera = load_split(args.sky, json.load(open(args.split)))
    chosen = best_settings("cmaes", pd.read_csv(args.tuning))
    rule = pd.concat([pd.read_csv(path) for path in sorted(glob.glob(args.rule_files))], ignore_index=True)
    if rule.empty:
        print(f"no files match {args.rule_files!r}", file=sys.stderr)
        return 2
    rows, frames = [], []
    for noise_level, own in rule.groupby("noise_level", sort=True):
        start = time.process_time()
        search = baseline_noise_runs("cmaes", train_set, int(noise_level), sorted(own["run"]), chosen, args.seed,
                                     camera=camera)
        cpu = (time.process_time() - start) / len(own)
        # run r of both is the paired run (level, r): its noise and seeds come from run_seed(seed, level, r)
        paired = own.set_index("run")["distance"].reindex(search["run"])
        ratio = paired.mean() / search["distance"].mean()
        rows.append({"noise_level": int(noise_level), "runs": len(search), "rule_mean_mm": 1e3 * paired.mean(),
                     "cmaes_mean_mm": 1e3 * search["distance"].mean(), "ratio": ratio,
                     "within_2x": bool(ratio <= CMAES_FACTOR), "cmaes_cpu_s_per_run": cpu})
        frames.append(search)
    print(f"rule: {rule['flow'].iloc[0]}; CMA-ES: {chosen}")
    print(pd.DataFrame(rows).round(3).to_string(index=False))
    if args.csv:
        pd.concat(frames).to_csv(args.csv, index=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Seconds per run of the Table 3 baselines: R runs one after another against R runs as one program.

    PYTHONPATH=src python benchmarks/speed/bench_baselines.py SKY.bin SPLIT.json [--runs 60] [--level 2]
        [--methods silhouette,chamfer,sinkhorn,cmaes] [--tuning-dir DIR] [--sequential-runs N]

For each method: runs ``r = 0..R-1`` at noise level ``L`` with Table 2's noisy targets (seed
``run_seed(0, L, r)``), the tuned settings (the ``best`` row of ``DIR/tuning_<method>.csv`` when the
file exists, else the defaults), fitted

* sequentially: ``fit`` once per run (the first ``--sequential-runs`` runs, default all R), and
* batched: ``fit_runs`` on all R runs at once,

in this one process on one thread (``torch.set_num_threads(1)``). Prints seconds per run of each
(wall time, and the process's CPU time, which other processes' load disturbs less), their ratios,
and the largest difference between the two ways' thetas over the runs both did
(metres; 0 means bit-identical). ``cmaes`` is measured only if ``sdm.experiments.baselines.cmaes`` has ``fit_runs``.
Timings on a shared machine are inflated; the ratio, taken in one process, is the figure to quote.

Measured 2026-11-23 (default data, level 2, R = 60, sequential on the first 10, a 2-core machine
shared with other jobs), CPU seconds per run sequential -> batched: chamfer 0.80 -> 0.59 (1.36x;
a second pass 1.39x), silhouette 1.56 -> 1.63 (0.95x), sinkhorn 2.25 -> 1.89 (1.19x); every
batched theta equal to its single run's to the bit. Batching shares little on one core because
the steps are arithmetic-bound, not overhead-bound: the float32 nearest-neighbour arg-mins
(chamfer), the splatted cells (silhouette) and the ``exp`` of geomloss's log-sum-exp (sinkhorn)
grow in proportion to the runs (torch.profiler: chamfer's ``argmin`` 1.8 ms per call for one run,
39 ms for 20; sinkhorn's ``exp_`` 0.36 ms and 8.0 ms).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import pandas as pd
import torch

from sdm.experiments.baselines import METHODS, best_settings
from sdm.experiments import load_split, noisy_targets, run_seed


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sky")
    parser.add_argument("split")
    parser.add_argument("--runs", type=int, default=60, help="R, runs at the level (one level's runs)")
    parser.add_argument("--level", type=int, default=2)
    parser.add_argument("--methods", default="silhouette,chamfer,sinkhorn,cmaes")
    parser.add_argument("--tuning-dir", default="/work/data-default/baselines",
                        help="where tuning_<method>.csv (the workflow's) are; defaults when missing")
    parser.add_argument("--sequential-runs", type=int, default=None,
                        help="time the sequential way on the first N runs only (default all R)")
    parser.add_argument("--seed", type=int, default=0, help="the experiment's seed (Table 2's noise.seed)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    train_set, _, _ = load_split(args.sky, json.load(open(args.split)))
    seeds = [run_seed(args.seed, args.level, run) for run in range(args.runs)]
    sets = [train_set.with_targets(noisy_targets(train_set.targets, args.level, seed)) for seed in seeds]
    n_sequential = args.runs if args.sequential_runs is None else min(args.sequential_runs, args.runs)
    rows = []
    for name in args.methods.split(","):
        entry = METHODS[name]
        if entry.fit_runs is None:
            print(f"# {name}: no fit_runs, skipped", file=sys.stderr)
            continue
        if entry.requires:
            try:
                __import__(entry.requires)
            except ImportError:
                print(f"# {name}: needs {entry.requires}, skipped", file=sys.stderr)
                continue
        tuning = Path(args.tuning_dir) / f"tuning_{name}.csv"
        settings = best_settings(name, pd.read_csv(tuning)) if tuning.exists() else entry.settings()
        start, start_cpu = time.perf_counter(), time.process_time()
        sequential = [entry.fit(data, settings, seed=seed) for data, seed in zip(sets[:n_sequential], seeds)]
        sequential_seconds = (time.perf_counter() - start) / n_sequential
        sequential_cpu = (time.process_time() - start_cpu) / n_sequential
        start, start_cpu = time.perf_counter(), time.process_time()
        batched = entry.fit_runs(sets, settings, seeds)
        batched_seconds = (time.perf_counter() - start) / args.runs
        batched_cpu = (time.process_time() - start_cpu) / args.runs
        difference = max(abs(x - y) for one, many in zip(sequential, batched) for x, y in zip(one.theta, many.theta))
        rows.append({"method": name, "runs": args.runs, "sequential_runs": n_sequential,
                     "sequential_s_per_run": sequential_seconds, "batched_s_per_run": batched_seconds,
                     "speedup": sequential_seconds / batched_seconds,
                     "sequential_cpu_s_per_run": sequential_cpu, "batched_cpu_s_per_run": batched_cpu,
                     "cpu_speedup": sequential_cpu / batched_cpu, "max_theta_difference_m": difference})
        print(f"# {name}: {rows[-1]}", file=sys.stderr, flush=True)
    pd.set_option("display.width", 200)
    print(f"Level {args.level}, R = {args.runs}, one thread; seconds per run (wall, then CPU)")
    print(pd.DataFrame(rows).to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    return 0


if __name__ == "__main__":
    sys.exit(main())

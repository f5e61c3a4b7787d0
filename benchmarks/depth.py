"""Depth table (issue 12): train (a, b, c) on a Sky split's training set retargeted to theta* = (a, b, c).

    PYTHONPATH=src python benchmarks/depth.py SKY.bin SPLIT.json [--depths -1,0.5,1] [--levels 0] [--runs 20] [--flow paper]

Run r at noise level n: targets of the shift (0.517, 0.303, c) (``sdm.depth.depth_targets``), moved by
noise n drawn from ``run_seed(0, n, r)``, which also shuffles; the tuned settings with ``fit_depth``.
Prints per (c, level) the mean |a - a*|, |b - b*| (1e-3 m) and |c - c*| (1e-2 m) and the distance in (a, b).
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace

import pandas as pd
import torch

from sdm.depth import depth_targets
from sdm.experiments import load_split, noisy_targets, run_seed, settings_for
from sdm.train import train

TUNED = dict(n_epoch=2, lr=1e-4, s=4, batch_size=16, lr_decay=0.5, seed=0)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sky")
    parser.add_argument("split")
    parser.add_argument("--depths", default="-1,0.5,1")
    parser.add_argument("--levels", default="0")
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--flow", default="paper")
    parser.add_argument("--depth-lr-scale", type=float, default=None, help="default TrainSettings'")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    train_set, _, _ = load_split(args.sky, json.load(open(args.split)))
    settings = replace(settings_for(**TUNED), fit_depth=True, flow=args.flow)
    if args.depth_lr_scale is not None:
        settings = replace(settings, depth_lr_scale=args.depth_lr_scale)
    rows = []
    for c in (float(v) for v in args.depths.split(",")):
        truth = (0.517, 0.303, c)
        clean = depth_targets(train_set, truth)
        for level in (int(v) for v in args.levels.split(",")):
            for run in range(args.runs):
                seed = run_seed(settings.seed, level, run)
                data = train_set.with_targets(noisy_targets(clean, level, seed))
                a, b, fitted = train(data, replace(settings, seed=seed), progress=False).final_theta
                rows.append({"c_true": c, "level": level, "run": run, "a": a, "b": b, "c": fitted})
            print(f"# c {c} level {level} done", file=sys.stderr, flush=True)
    frame = pd.DataFrame(rows)
    frame["err_a_mm"] = 1e3 * (frame.a - 0.517).abs()
    frame["err_b_mm"] = 1e3 * (frame.b - 0.303).abs()
    frame["err_c_cm"] = 1e2 * (frame.c - frame.c_true).abs()
    frame["dist_ab_mm"] = (frame.err_a_mm ** 2 + frame.err_b_mm ** 2) ** 0.5
    table = frame.groupby(["c_true", "level"])[["err_a_mm", "err_b_mm", "err_c_cm", "dist_ab_mm"]].mean()
    table["runs"] = frame.groupby(["c_true", "level"]).size()
    print("Depth: mean absolute errors (a, b in 1e-3 m; c in 1e-2 m)")
    print(table.round(3).to_string())
    return 0


if __name__ == "__main__":
    sys.exit(main())

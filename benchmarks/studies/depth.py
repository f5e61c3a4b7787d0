"""Depth table: train (a, b, c) on a Sky split's training set retargeted to theta* = (a, b, c).

    PYTHONPATH=src python benchmarks/studies/depth.py SKY.bin SPLIT.json [--depths -1,0.5,1] [--levels 0] [--runs 20] [--flow paper]
        [--depth-lr-scale 20] [--depth-zoom 1] [--epochs 2] [--group 20] [--csv runs.csv]

Run r at noise level n: targets of the shift (0.517, 0.303, c) (``sdm.depth.depth_targets``), moved by
noise n drawn from ``run_seed(0, n, r)``, which also shuffles; the tuned settings with ``fit_depth``.
Runs are Table 5's (``sdm.experiments.depth_noise_runs``), ``--group`` at a time (each as ``train`` alone, to 1e-12 m).
Prints per (c, level) the mean |a - a*|, |b - b*| (1e-3 m) and |c - c*| (1e-2 m) and the distance in (a, b).
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace

import pandas as pd
import torch

from sdm.experiments import depth_noise_runs, load_split, settings_for

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
    parser.add_argument("--group", type=int, default=20, help="runs trained together (group_size)")
    parser.add_argument("--epochs", type=int, default=None, help="n_epoch (default the tuned 2)")
    parser.add_argument("--depth-zoom", type=int, default=None, help="finest level moving c (default TrainSettings')")
    parser.add_argument("--csv", help="write the per-run rows here")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    train_set, _, _ = load_split(args.sky, json.load(open(args.split)))
    settings = replace(settings_for(**TUNED), fit_depth=True, rule=args.flow)
    if args.depth_lr_scale is not None:
        settings = replace(settings, depth_lr_scale=args.depth_lr_scale)
    if args.depth_zoom is not None:
        settings = replace(settings, depth_zoom=args.depth_zoom)
    if args.epochs is not None:
        settings = replace(settings, n_epoch=args.epochs)
    frames = []
    for c in (float(v) for v in args.depths.split(",")):
        for noise_level in (int(v) for v in args.levels.split(",")):
            # Table 5's runs (sdm.experiments.depth_noise_runs), --group at a time (each as train() alone, to 1e-12 m).
            runs = depth_noise_runs(train_set, c, noise_level, range(args.runs), settings, shift=(0.517, 0.303),
                                    group_size=args.group)
            frames.append(runs[["c_true", "noise_level", "run", "a", "b", "c"]])
            print(f"# c {c} level {noise_level} done", file=sys.stderr, flush=True)
    frame = pd.concat(frames, ignore_index=True)
    frame["err_a_mm"] = 1e3 * (frame.a - 0.517).abs()
    frame["err_b_mm"] = 1e3 * (frame.b - 0.303).abs()
    frame["err_c_cm"] = 1e2 * (frame.c - frame.c_true).abs()
    frame["dist_ab_mm"] = (frame.err_a_mm ** 2 + frame.err_b_mm ** 2) ** 0.5
    # Signed mean errors: a bias (all runs off the same way) versus a spread.
    frame["bias_a_mm"] = 1e3 * (frame.a - 0.517)
    frame["bias_b_mm"] = 1e3 * (frame.b - 0.303)
    frame["bias_c_cm"] = 1e2 * (frame.c - frame.c_true)
    columns = ["err_a_mm", "err_b_mm", "err_c_cm", "dist_ab_mm", "bias_a_mm", "bias_b_mm", "bias_c_cm"]
    table = frame.groupby(["c_true", "noise_level"])[columns].mean()
    table["runs"] = frame.groupby(["c_true", "noise_level"]).size()
    print("Depth: mean absolute errors (a, b in 1e-3 m; c in 1e-2 m)")
    print(table.round(3).to_string())
    if args.csv:
        frame.to_csv(args.csv, index=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())

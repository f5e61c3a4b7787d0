"""Speed of the SDM layer: fast point rows against the dense grid reference, and a full training run.

Prints, in one run on one thread:
  * ms per training step (batch of 16 configurations, forward + backward, the
    chain from level s = 4 down to the loss level) for the fast and the dense
    path at each zoom level, and their ratio;
  * the wall time of one full training run (512 configurations, 5 levels, 1 epoch);
  * the time to build the default Sky data set (4,248 configurations) on one core.

Ratios are measured in the same run, so they hold on a noisy machine; the
absolute figures are for reading, never for asserting.

    python benchmarks/bench_sdm.py [--configs 512] [--seed 0] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import statistics
import time

import torch
import torch.nn.functional as F

from sdm.batch import ConfigurationSet
from sdm.data import build_sky_dataset
from sdm.data.synthetic import synthetic_images
from sdm.mapping import SpatialDomainMapping
from sdm.train import TrainSettings, train


def step_ms(data: ConfigurationSet, method: str, zoom: int, repeats: int, batch_size: int = 16) -> float:
    """Median ms of one SGD step (gather, forward, backward) at loss level ``zoom``."""
    layer = SpatialDomainMapping(data.camera, s=4, zoom=zoom, method=method)
    theta = torch.tensor([0.3, 0.2], dtype=torch.float64, requires_grad=True)
    pyramid = data.pyramid(4)
    times = []
    for repeat in range(repeats + 1):
        indices = torch.arange(batch_size) + (repeat * batch_size) % (len(data) - batch_size)
        start = time.perf_counter()
        batch = data.batch(indices)
        out = layer(batch.points + F.pad(theta, (0, 1)), batch.pixels, pyramid[zoom].index_select(0, indices),
                    batch.config, batch.rank, target_is_zoomed=True)
        theta.grad = None
        out.loss.backward()
        if repeat:  # the first call warms up allocators and caches
            times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", type=int, default=512)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fast-repeats", type=int, default=60)
    parser.add_argument("--dense-repeats", type=int, default=3)
    parser.add_argument("--json", help="also write the figures to this JSON file")
    args = parser.parse_args()
    torch.set_num_threads(1)

    images = synthetic_images(5277, seed=args.seed)
    start = time.perf_counter()
    configurations = build_sky_dataset(images, n_sample=4248, seed=args.seed, progress=False)
    build_s = time.perf_counter() - start
    print(f"building the default Sky data set (4,248 configurations): {build_s:.1f} s (target: at most 30 s)")
    data = ConfigurationSet.from_configurations(configurations[: args.configs])
    print(f"{len(data)} synthetic configurations, {data.points.shape[0] / len(data):.0f} points each on average; "
          f"torch {torch.__version__}, 1 thread\n")

    rows = []
    print(f"{'zoom':>4} {'fast ms/step':>13} {'dense ms/step':>14} {'dense/fast':>11}")
    for zoom in range(4, -1, -1):
        fast = step_ms(data, "fast", zoom, args.fast_repeats)
        dense = step_ms(data, "dense", zoom, args.dense_repeats)
        rows.append({"zoom": zoom, "fast_ms": fast, "dense_ms": dense, "ratio": dense / fast})
        print(f"{zoom:>4} {fast:>13.2f} {dense:>14.1f} {dense / fast:>10.0f}x")

    runs = []
    for _ in range(5):
        start = time.perf_counter()
        history = train(data, TrainSettings(lr=3e-4, n_epoch=1), progress=False)
        runs.append(time.perf_counter() - start)
    steps = len(history.loss)
    print(f"\nfull training run ({len(data)} configurations, 5 levels, 1 epoch, {steps} steps): "
          f"median {statistics.median(runs):.3f} s, best {min(runs):.3f} s over {len(runs)} runs "
          f"({1000 * statistics.median(runs) / steps:.2f} ms/step)")
    if args.json:
        with open(args.json, "w") as handle:
            json.dump({"steps": rows, "training_run_s": runs, "configs": len(data), "sky_build_s": build_s}, handle, indent=2)


if __name__ == "__main__":
    main()

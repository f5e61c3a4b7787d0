"""CPU seconds per configuration of CMA-ES on per-row shifts, against the number of cars per image.

    PYTHONPATH=src python benchmarks/speed/bench_rows.py [--cars 1 2 4 8] [--configs 12] [--default 36] [--floor]

Protocol: one thread, one process. For each ``K`` of ``--cars``: ``--configs`` images of ``K`` cars on a
screen grid (``tests/sharing_scenes.py``: discs apart, depths 12-60 m), one row per car, theta* drawn
from :class:`sdm.sharing.TruthDistribution` (seed 0), noise-free targets rendered from it; then
``--default`` images of the default synthetic data (:func:`sdm.experiments.data.synthetic.synthetic_images`, seed 0;
overlapping discs, the cars per point by the ``rmin`` winner) the same way. CMA-ES per configuration
(:func:`sdm.experiments.baselines.rows.fit_configurations`, default settings) and, with ``--floor``, the floor per
configuration. Prints per ``K``: the unknowns, CPU seconds per configuration (mean, max), counts per
configuration, the share of configurations at mismatch 0, and the per-car distance (mean, median, Q3).
The machine's load inflates the seconds (process time counts only the time the run had the core). numpy's
BLAS runs on one thread (``OPENBLAS_NUM_THREADS=1`` unless set), as in the workflow's stages.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

# pycma's eigendecompositions go through numpy's BLAS: with its default thread pool on a shared machine a
# 32 x 32 decomposition took 19 ms instead of 0.3 ms (as the workflow's stages, one thread)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))

from sharing_scenes import car_grid_scene, set_with_cars  # noqa: E402

from sdm import sharing  # noqa: E402
from sdm.experiments.baselines import rows  # noqa: E402
from sdm.experiments.data.synthetic import synthetic_images  # noqa: E402
from sdm.sky import build_configuration  # noqa: E402


def default_set(n_images: int):
    """``set_with_cars`` of the first ``n_images`` default synthetic images that have a car on screen."""
    configs = [build_configuration(image.centres, image_id=image.image_id) for image in synthetic_images(n_images)]
    return set_with_cars([c for c in configs if c.num_points])


def measure(name: str, data, cars, n_cars, floor: bool) -> None:
    layout = sharing.per_car(data, cars, n_cars)
    truth = sharing.draw_truth(layout, 0)
    shifted = sharing.shifted_set(data, truth, layout.param_index)
    units = sharing.units(shifted, layout.param_index, layout.n_rows)
    totals = sharing.unit_totals(truth, units)
    start = time.process_time()
    result = rows.fit_configurations(shifted, units, seed=0)
    total = time.process_time() - start
    summary = sharing.summarise_distances(sharing.row_distances(result.totals, totals),
                                          hidden_without_row=len(layout.hidden))
    per_config = units.offsets[1:] - units.offsets[:-1]
    print(f"{name:>10}  unknowns {2 * float(per_config.double().mean()):5.1f}  "
          f"CPU s/config {float(result.seconds.mean()):.3f} (max {float(result.seconds.max()):.3f}, "
          f"all {total / len(shifted):.3f})  counts/config {float(result.evaluations.double().mean()):7.0f}  "
          f"at 0: {float((result.mismatch == 0).double().mean()):.2f}  distance mean {summary.mean:.4f} "
          f"median {summary.median:.4f} Q3 {summary.q3:.4f} m ({summary.counted} cars, {summary.hidden} hidden)")
    if floor:
        result = rows.floor_configurations(shifted, units, totals, seed=0)
        summary = sharing.summarise_distances(sharing.row_distances(result.totals, totals))
        print(f"{'floor':>10}  CPU s/config {float(result.seconds.mean()):.3f}  counts/config "
              f"{float(result.evaluations.double().mean()):7.0f}  distance mean {summary.mean:.4f} "
              f"median {summary.median:.4f} Q3 {summary.q3:.4f} m")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cars", type=int, nargs="+", default=[1, 2, 4, 8])
    parser.add_argument("--configs", type=int, default=12)
    parser.add_argument("--default", type=int, default=36, help="default-data images (0: none)")
    parser.add_argument("--floor", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(1)
    rows.fit_configurations(*_warm())  # imports pycma outside the timings
    for n_cars in args.cars:
        measure(f"K = {n_cars}", *car_grid_scene(n_cars, args.configs, seed=0), args.floor)
    if args.default:
        measure("default", *default_set(args.default), args.floor)


def _warm():
    data, cars, n_cars = car_grid_scene(1, 1, seed=1)
    layout = sharing.per_car(data, cars, n_cars)
    return data, sharing.units(data, layout.param_index, layout.n_rows)


if __name__ == "__main__":
    main()

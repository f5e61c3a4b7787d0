"""Seconds per CMA-ES run (Table 3's ``cmaes`` baseline): the straightforward count against the fast ones.

    PYTHONPATH=src python benchmarks/speed/bench_cmaes.py SKY.bin SPLIT.json [--tuning TUNING_CMAES.csv] [--level 2] [--runs 20]

Protocol: the training set of the split; the tuned settings (the row of the tuning CSV with
``best`` True, else the defaults); the noisy targets and seeds of Table 2's runs
``run_seed(0, level, r)``, r = 0..R-1; one thread, one process. Four ways, the same runs:

* ``reference``: every evaluation by :meth:`PixelMismatch.reference` (the count as committed before
  the fast one: a fresh ``N x H x W`` bitmap per call), each run building its own objective;
* ``fit_runs (torch count)``: :func:`sdm.experiments.baselines.cmaes.fit_runs` over chunks of ``--chunk`` runs,
  the grouped count in torch, one candidate at a time (``sdm.mapping.native.disabled``: the path
  without a C compiler or with ``SDM_NATIVE=0``);
* ``fit``: :func:`sdm.experiments.baselines.cmaes.fit` per run (compiled count, own set-up per run);
* ``fit_runs``: the same chunks with the compiled count (a generation per call, set-up shared).

Asserts that the four give the same theta and evaluation count for every run, then prints the
seconds per run and the ratios. The machine's load inflates the seconds; the ratios, taken in one
process on the same runs, are the figures to quote, the CPU-time ones first (one thread: process
time is the time the run had the core).
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import pandas as pd
import torch

from sdm.experiments.baselines import cmaes, mismatch
from sdm.experiments.baselines.common import FitResult
from sdm.experiments import load_split, noisy_targets, run_seed
from sdm.mapping import native


class _ReferenceLayout:
    """What :meth:`PixelMismatch.reference` takes from its layout (the projection), without the grouping."""

    def __init__(self, train_set, camera) -> None:
        self.camera, self._points, self._counts, self._reference = camera, train_set.points, train_set.counts, None

    reference_terms = mismatch.ShiftLayout.reference_terms


class ReferenceMismatch(mismatch.PixelMismatch):
    """:class:`PixelMismatch` counted by :meth:`reference` only, without building the fast layout."""

    def __init__(self, train_set, camera=None) -> None:
        self.camera = camera or train_set.camera
        self.train_set = train_set
        self.layout = _ReferenceLayout(train_set, self.camera)
        self.evaluations = 0
        self._active = train_set.targets.nonzero()

    def many(self, thetas) -> list[int]:
        self.evaluations += len(thetas)
        return [self.reference(theta) for theta in thetas]


def reference_fit(train_set, settings, seed) -> FitResult:
    start = time.perf_counter()
    result = cmaes.cmaes_search(ReferenceMismatch(train_set), settings, seed, (0.0, 0.0))
    result.seconds = time.perf_counter() - start
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sky")
    parser.add_argument("split")
    parser.add_argument("--tuning", help="tuning_cmaes.csv of the baseline stage (row with best=True)")
    parser.add_argument("--level", type=int, default=2, help="noise level of the runs")
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--chunk", type=int, default=10, help="runs per fit_runs call (the ways alternate per chunk)")
    parser.add_argument("--reference-runs", type=int, default=None,
                        help="runs timed with the reference count (default: all; it is the slow one)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    train_set, _, _ = load_split(args.sky, json.load(open(args.split)))
    settings = cmaes.CMAESSettings()
    if args.tuning:
        tuning = pd.read_csv(args.tuning)
        best = tuning[tuning["best"].astype(bool)].iloc[0]
        settings = cmaes.CMAESSettings(sigma0=float(best["sigma0"]), budget=int(best["budget"]),
                                       popsize=int(best["popsize"]), tolx=float(best["tolx"]))
    seeds = [run_seed(0, args.level, run) for run in range(args.runs)]
    sets = [train_set.with_targets(noisy_targets(train_set.targets, args.level, seed)) for seed in seeds]
    n_reference = args.runs if args.reference_runs is None else min(args.reference_runs, args.runs)
    print(f"{len(train_set)} configurations, {train_set.points.shape[0]} points; {settings}; level {args.level}, "
          f"{args.runs} runs ({n_reference} with the reference count); 1 thread", flush=True)

    import cma  # noqa: F401  (imported once per process in the workflow too; its import, ~1-3 s, is timed by nobody)

    # Interleaved in chunks of runs (fit_runs over the chunk, then fit and the reference count run by run),
    # so that a change of the machine's load during the benchmark hits the three ways alike.
    cpu = {"reference (before)": 0.0, "fit_runs (torch count)": 0.0, "fit (after)": 0.0, "fit_runs (after)": 0.0}
    wall_batched = wall_torch = 0.0
    batched, torch_count, single, reference = [], [], [], []
    stride = max(args.runs // max(n_reference, 1), 1)
    for first in range(0, args.runs, args.chunk):
        chunk = range(first, min(first + args.chunk, args.runs))
        start, start_wall = time.process_time(), time.perf_counter()
        batched += cmaes.fit_runs([sets[run] for run in chunk], settings, [seeds[run] for run in chunk])
        cpu["fit_runs (after)"] += time.process_time() - start
        wall_batched += time.perf_counter() - start_wall
        start, start_wall = time.process_time(), time.perf_counter()
        with native.disabled():
            torch_count += cmaes.fit_runs([sets[run] for run in chunk], settings, [seeds[run] for run in chunk])
        cpu["fit_runs (torch count)"] += time.process_time() - start
        wall_torch += time.perf_counter() - start_wall
        for run in chunk:
            start = time.process_time()
            single.append(cmaes.fit(sets[run], settings, seed=seeds[run]))
            cpu["fit (after)"] += time.process_time() - start
            if run % stride == 0 and len(reference) < n_reference:  # spread over the chunks
                start = time.process_time()
                reference.append(reference_fit(sets[run], settings, seeds[run]))
                cpu["reference (before)"] += time.process_time() - start
    cpu = {name: seconds / (len(reference) if name.startswith("reference") else args.runs) for name, seconds in cpu.items()}
    for run, (one, many, counted) in enumerate(zip(single, batched, torch_count)):
        assert one.theta == many.theta and one.evaluations == many.evaluations, f"run {run}: fit_runs != fit"
        assert counted.history == many.history, f"run {run}: torch count != compiled count"
    for index, ref in enumerate(reference):
        one = single[index * stride]
        assert one.theta == ref.theta and one.evaluations == ref.evaluations, f"run {index * stride}: fast != reference"

    wall = {
        "reference (before)": sum(r.seconds for r in reference) / len(reference),
        "fit_runs (torch count)": wall_torch / args.runs,
        "fit (after)": sum(r.seconds for r in single) / args.runs,
        "fit_runs (after)": wall_batched / args.runs,
    }
    evaluations = sum(r.evaluations for r in single) / args.runs
    print(f"same theta and evaluations in all four ways; {evaluations:.1f} evaluations per run")
    print("seconds per run: wall (FitResult.seconds) and CPU (process time: what the load does not inflate)")
    for name in wall:
        print(f"{name:22s} wall {wall[name]:7.3f} s  x{wall['reference (before)'] / wall[name]:5.2f}   "
              f"cpu {cpu[name]:7.3f} s  x{cpu['reference (before)'] / cpu[name]:5.2f}   "
              f"{1e3 * cpu[name] / evaluations:6.2f} cpu ms/evaluation")
    return 0


if __name__ == "__main__":
    sys.exit(main())

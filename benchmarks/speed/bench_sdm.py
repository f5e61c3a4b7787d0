"""Speed of the SDM layer: fast point rows against the dense grid reference, and a full training run.

Prints, in one run on one thread:
  * ms per training step (batch of 16 configurations, forward + backward, the
    chain from level s = 4 down to the loss level) for the fast path with the
    compiled CPU kernel (:mod:`sdm.mapping.native`), the fast path's torch
    operations alone, and the dense path at each zoom level, and their ratios;
  * ms per full training run (512 configurations, 5 levels, 1 epoch): compiled (the whole
    run in one kernel call, :func:`sdm.train.train_runs`) and on the torch path, and the ratio;
  * a run with a shift per car (parameters attached to points: ``train_runs(param_index=)``, one row per car
    that owns points, each at the same rate per point) against the shared run on the same points, targets and
    settings, timed alternately, and the ratio;
  * the time to build the default Sky data set (4,248 configurations) on one core;
  * many runs as one program: ``--runs`` (30) noise runs at noise level 2
    trained one after another (:func:`sdm.experiments.noise_runs` with groups of one run) and
    together (one group of ``--runs``, and the default group size), ms per run-step of each and
    the ratio;
  * all of Table 2: 5 noise levels x ``--table2-runs`` (60) runs, 512 training
    configurations, the tuned settings of the default workflow (n_epoch 2, lr 1e-4),
    batched with the default group size, compiled; and the torch path's time for them,
    extrapolated from one group per level, with the ratio;
  * the GPU's figures are ``benchmarks/speed/bench_gpu.py``'s (``make bench`` runs both).

Times are given as wall seconds and as CPU seconds of this process (the
latter is what one core spends, whatever else runs on the machine). Ratios are
measured in the same run, so they hold on a noisy machine; the absolute figures
are for reading, never for asserting.

    python benchmarks/speed/bench_sdm.py [--configs 512] [--seed 0] [--train-repeats 20] [--runs 30] [--table2-runs 60]
                                   [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import statistics
import time

import torch

from sdm.batch import ConfigurationSet
from sdm.experiments.data import build_sky_dataset
from sdm.experiments.data.synthetic import synthetic_images
from sdm.experiments import NOISE_GROUP_SIZE, noise_runs
from sdm.mapping import SpatialDomainMapping, native
from sdm.sky import shift_vector
from sdm.train import TrainSettings, rates_per_point, train, train_runs

#: Table 2's settings in the default workflow: the tuned cell (n_epoch 2, lr 1e-4), s = 4, batches of 16.
TABLE2_SETTINGS = TrainSettings(lr=1e-4, n_epoch=2, batch_size=16, s=4, zoom=0, lr_decay=0.5, seed=0)
TABLE2_LEVELS = (0, 1, 2, 3, 4)


class Clock:
    """Wall and CPU seconds of a block (CUDA work is waited for before reading the clocks)."""

    def __init__(self, device: str = "cpu") -> None:
        self.device = device

    def __enter__(self) -> "Clock":
        self._sync()
        self.wall, self.cpu = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *_) -> None:
        self._sync()
        self.wall, self.cpu = time.perf_counter() - self.wall, time.process_time() - self.cpu

    def _sync(self) -> None:
        if self.device != "cpu":
            torch.cuda.synchronize()


def runs_together_vs_alone(data: ConfigurationSet, n_runs: int, device: str) -> dict:
    """``n_runs`` noise runs (level 2) one after another, then as one group, then in default-size groups."""
    steps = 5 * TABLE2_SETTINGS.n_epoch * (len(data) // TABLE2_SETTINGS.batch_size)
    data = data.to(device)
    with Clock(device) as alone:
        noise_runs(data, 2, range(n_runs), TABLE2_SETTINGS, group_size=1)
    with native.disabled(), Clock(device) as alone_torch:  # the same runs without the kernel (as before it)
        noise_runs(data, 2, range(n_runs), TABLE2_SETTINGS, group_size=1)
    with Clock(device) as together:
        noise_runs(data, 2, range(n_runs), TABLE2_SETTINGS, group_size=n_runs)
    with Clock(device) as grouped:
        noise_runs(data, 2, range(n_runs), TABLE2_SETTINGS)
    out = {"device": device, "runs": n_runs, "steps_per_run": steps, "group_size_default": NOISE_GROUP_SIZE,
           "configs": len(data)}
    for name, clock in (("sequential", alone), ("sequential_torch_path", alone_torch), ("one_group", together),
                        ("default_groups", grouped)):
        out[name] = {"wall_s": clock.wall, "cpu_s": clock.cpu,
                     "ms_per_run_step": 1000 * clock.wall / (n_runs * steps)}
    out["ratio_one_group"] = alone.wall / together.wall
    out["ratio_default_groups"] = alone.wall / grouped.wall
    out["ratio_one_group_cpu"] = alone.cpu / together.cpu
    out["ratio_default_groups_vs_torch_path"] = alone_torch.wall / grouped.wall
    return out


def table2(data: ConfigurationSet, runs_per_level: int, device: str, sample_runs: int = NOISE_GROUP_SIZE) -> dict:
    """All Table 2 runs (5 levels x ``runs_per_level``), batched in default-size groups (compiled on the CPU).

    On the CPU also the torch path's time for all of them, extrapolated from ``sample_runs`` runs at each
    level (one default-size group per level).
    """
    data = data.to(device)
    n_runs = len(TABLE2_LEVELS) * runs_per_level
    with Clock(device) as clock:
        for noise_level in TABLE2_LEVELS:
            noise_runs(data, noise_level, range(runs_per_level), TABLE2_SETTINGS)
    out = {"device": device, "runs": n_runs, "wall_s": clock.wall, "cpu_s": clock.cpu}
    if device == "cpu":
        with native.disabled(), Clock(device) as sample:
            for noise_level in TABLE2_LEVELS:
                noise_runs(data, noise_level, range(sample_runs), TABLE2_SETTINGS)
        scale = n_runs / (len(TABLE2_LEVELS) * sample_runs)
        out |= {"torch_path_sample_runs": len(TABLE2_LEVELS) * sample_runs,
                "torch_path_wall_s_extrapolated": sample.wall * scale,
                "torch_path_cpu_s_extrapolated": sample.cpu * scale}
    return out


def report_runs(runs: dict) -> None:
    n, steps = runs["runs"], runs["steps_per_run"]
    print(f"\n{n} noise runs (level 2, {runs['configs']} configurations, n_epoch 2, lr 1e-4: {steps} steps each) "
          f"on {runs['device']}:")
    for name in ("sequential_torch_path", "sequential", "one_group", "default_groups"):
        label = {"sequential_torch_path": "one after another, torch path", "sequential": "one after another",
                 "one_group": f"as one group of {n}",
                 "default_groups": f"in groups of {runs['group_size_default']}"}[name]
        row = runs[name]
        print(f"  {label:>30}: {row['wall_s']:7.1f} s wall, {row['cpu_s']:7.1f} s CPU, "
              f"{row['ms_per_run_step']:6.3f} ms per run-step "
              f"({n * row['ms_per_run_step']:.1f} ms per step of all {n})")
    print(f"  speed-up of one group over one after another: {runs['ratio_one_group']:.2f}x wall "
          f"({runs['ratio_one_group_cpu']:.2f}x CPU); default groups: {runs['ratio_default_groups']:.2f}x "
          f"(on the CPU each compiled run is its own loop: packing runs is for the torch path, i.e. the GPU); "
          f"default groups against one after another on the torch path: "
          f"{runs['ratio_default_groups_vs_torch_path']:.2f}x")


def car_against_shared(data: ConfigurationSet, repeats: int) -> dict:
    """CPU ms of a training run with one row per car (:meth:`ConfigurationSet.car_rows`, rows at the same rate per
    point) and of the shared run on the same points and targets (the compiled path where the kernel is built),
    timed alternately (median of ``repeats`` each). Twice: with the schedule's rate (lr 3e-4), where the per-car
    rows follow other paths than the shared shift and so pull other numbers of points; and with lr 1e-12, where
    nothing moves and both runs pull the same points at every step: the engine's own cost of the rows."""
    index, _ = data.car_rows()
    row_rate = rates_per_point(index)
    out = {"rows": int(index.max()) + 1}
    for name, lr in (("", 3e-4), ("still_", 1e-12)):
        settings = [TrainSettings(lr=lr, n_epoch=1)]
        shared, car = [], []
        for _ in range(repeats):
            with Clock() as clock:
                train_runs(data, [data.targets], settings)
            shared.append(clock.cpu)
            with Clock() as clock:
                train_runs(data, [data.targets], settings, param_index=index, row_rate=row_rate)
            car.append(clock.cpu)
        shared_ms, car_ms = 1000 * statistics.median(shared), 1000 * statistics.median(car)
        out |= {f"{name}shared_ms": shared_ms, f"{name}car_ms": car_ms, f"{name}ratio": car_ms / shared_ms}
    return out


def step_ms(data: ConfigurationSet, method: str, zoom: int, repeats: int, batch_size: int = 16) -> float:
    """Median ms of one SGD step (gather, forward, backward, update) at loss level ``zoom``, on the set's device
    (synchronised around each step)."""
    layer = SpatialDomainMapping(data.camera, s=4, zoom=zoom, method=method)
    theta = torch.tensor([0.3, 0.2], dtype=torch.float64, device=data.device, requires_grad=True)
    pyramid = data.pyramid(4)
    times = []
    for repeat in range(repeats + 1):
        indices = (torch.arange(batch_size) + (repeat * batch_size) % (len(data) - batch_size)).to(data.device)
        with Clock(data.device.type) as clock:
            batch = data.batch(indices)
            out = layer(batch.points + shift_vector(theta, batch.points), batch.pixels,
                        pyramid[zoom].index_select(0, indices), batch.config, batch.rank, target_is_zoomed=True)
            theta.grad = None
            out.loss.backward()
            with torch.no_grad():
                theta -= 1e-4 * theta.grad
        if repeat:  # the first call warms up allocators and caches
            times.append(clock.wall)
    return 1000 * statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", type=int, default=512)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fast-repeats", type=int, default=60)
    parser.add_argument("--dense-repeats", type=int, default=3)
    parser.add_argument("--train-repeats", type=int, default=20, help="compiled training runs timed (median)")
    parser.add_argument("--runs", type=int, default=30, help="runs for the together-vs-alone comparison")
    parser.add_argument("--table2-runs", type=int, default=60,
                        help="runs per noise level for the Table 2 timing (0: skip)")
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

    print(f"compiled CPU kernel: {'in use' if native.enabled() else 'NOT available (torch path only)'}\n")
    rows = []
    print(f"{'zoom':>4} {'kernel ms/step':>15} {'torch ms/step':>14} {'dense ms/step':>14} {'torch/kernel':>13} "
          f"{'dense/kernel':>13}")
    for zoom in range(4, -1, -1):
        fast = step_ms(data, "fast", zoom, args.fast_repeats)
        with native.disabled():
            torch_path = step_ms(data, "fast", zoom, args.fast_repeats)
        dense = step_ms(data, "dense", zoom, args.dense_repeats)
        rows.append({"zoom": zoom, "fast_ms": fast, "fast_torch_ms": torch_path, "dense_ms": dense,
                     "ratio": dense / fast, "ratio_torch": torch_path / fast})
        print(f"{zoom:>4} {fast:>15.2f} {torch_path:>14.2f} {dense:>14.1f} {torch_path / fast:>12.2f}x "
              f"{dense / fast:>12.0f}x")

    def training_runs(count: int) -> tuple[list[float], list[float], int]:
        """Wall and CPU seconds of ``count`` full training runs, and the steps of one."""
        walls, cpus = [], []
        for _ in range(count):
            with Clock() as clock:
                history = train(data, TrainSettings(lr=3e-4, n_epoch=1), progress=False)
            walls.append(clock.wall), cpus.append(clock.cpu)
        return walls, cpus, len(history.loss)

    runs, runs_cpu, steps = training_runs(args.train_repeats)  # compiled: the whole run in one kernel call
    with native.disabled():
        torch_runs, torch_runs_cpu, _ = training_runs(3)
    compiled_ms, torch_ms = 1000 * statistics.median(runs), 1000 * statistics.median(torch_runs)
    print(f"\none training run ({len(data)} configurations, 5 levels, 1 epoch, {steps} steps; median of "
          f"{len(runs)} and {len(torch_runs)}): compiled {compiled_ms:.1f} ms wall "
          f"({1000 * statistics.median(runs_cpu):.1f} ms CPU), torch path {torch_ms:.1f} ms wall "
          f"({1000 * statistics.median(torch_runs_cpu):.1f} ms CPU): {torch_ms / compiled_ms:.1f}x wall, "
          f"{statistics.median(torch_runs_cpu) / statistics.median(runs_cpu):.1f}x CPU "
          f"(targets: at most 25 ms, at least 12x)")

    per_car = car_against_shared(data, args.train_repeats)
    print(f"\none run with a shift per car ({per_car['rows']} rows, {len(data)} configurations, lr 3e-4 per point-mass, "
          f"n_epoch 1; median of {args.train_repeats}, alternating): {per_car['car_ms']:.1f} ms CPU against the shared "
          f"shift's {per_car['shared_ms']:.1f} ms on the same points: {per_car['ratio']:.2f}x (target: at most 1.5x); "
          f"with nothing moving (lr 1e-12, the same points pulled at every step): {per_car['still_car_ms']:.1f} ms "
          f"against {per_car['still_shared_ms']:.1f} ms, {per_car['still_ratio']:.2f}x")

    many, tables = [], []
    for device in ["cpu"]:  # the GPU's figures: benchmarks/speed/bench_gpu.py
        many.append(runs_together_vs_alone(data, args.runs, device))
        report_runs(many[-1])
        if args.table2_runs:
            tables.append(table2(data, args.table2_runs, device))
            t2 = tables[-1]
            target = "at most 15 s on one core"
            print(f"\nall {t2['runs']} Table 2 runs (5 levels x {args.table2_runs}, n_epoch 2, lr 1e-4, groups of "
                  f"{NOISE_GROUP_SIZE}) on {device}{', compiled' if device == 'cpu' else ''}: {t2['wall_s']:.1f} s "
                  f"wall, {t2['cpu_s']:.1f} s CPU (target: {target})")
            if "torch_path_wall_s_extrapolated" in t2:
                print(f"  torch path, extrapolated from {t2['torch_path_sample_runs']} runs: "
                      f"{t2['torch_path_wall_s_extrapolated']:.1f} s wall, {t2['torch_path_cpu_s_extrapolated']:.1f} s "
                      f"CPU: the compiled runs {t2['torch_path_wall_s_extrapolated'] / t2['wall_s']:.1f}x faster "
                      f"(wall), {t2['torch_path_cpu_s_extrapolated'] / t2['cpu_s']:.1f}x (CPU)")
    if args.json:
        with open(args.json, "w") as handle:
            json.dump({"steps": rows, "training_run_s": runs, "training_run_torch_path_s": torch_runs,
                       "configs": len(data), "sky_build_s": build_s, "per_car": per_car,
                       "runs_together_vs_alone": many, "table2": tables}, handle, indent=2)


if __name__ == "__main__":
    main()

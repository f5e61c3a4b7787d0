"""The GPU section of ``make bench``: the layer, Table 2 and Table 7's networks on a CUDA device.

Prints, in one run, where ``torch.cuda.is_available()`` (else one line saying so, and exit 0):

  * ms per training step (batch of 16 configurations, forward + backward + the update of theta, the chain from
    zoom s = 4 down to the loss's zoom) of the SDM layer (:class:`sdm.mapping.SpatialDomainMapping`, the fast
    path, torch operations) at zoom 4..0 on the GPU; with ``--author-layer PATH`` (the author's ``smap/smap.py``,
    github.com/thienannguyen-cv/SMap, kept outside the repository) also the author's layer on the same device,
    the same batches and the same step (its ``SMap(n=4)``, input images ``(B, 4, H, W)`` of the points'
    ``(x, y, z)`` scaled as its tutorial does and the mask, an L1 loss against the target at the zoom), and the
    ratio. Medians of ``--step-repeats`` steps after a warm-up step, the device synchronised around each;
  * Table 2's runs (``--table2-levels``, default all 5, x ``--table2-runs``, 512 configurations, the tuned
    cell n_epoch 2, lr 1e-4) on the GPU, packed ``--group-sizes`` runs at a time
    (:func:`sdm.experiments.noise_runs`), wall seconds; and their theta against the same runs on the CPU
    (the compiled kernel, one thread; the largest difference, metres);
  * one epoch of Table 7's network training per loss (:func:`sdm.experiments.network.train_network`: 3,000 configurations,
    batch 16, 187 steps, zoom 0) on the GPU and on the CPU (one thread, as a workflow job runs it), wall
    seconds and the ratio; every loss first trains two steps on the GPU, so that the device's set-up is
    nobody's epoch.

``--json`` writes the figures; ``--markdown`` writes them as the tables of a Markdown page.
Timings are for reading, never for asserting; the ratios are measured in this one run.

    python benchmarks/speed/bench_gpu.py [--author-layer smap.py] [--json out.json] [--markdown out.md]
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import platform
import statistics
import time
import traceback

import numpy as np
import torch

from bench_sdm import TABLE2_LEVELS, TABLE2_SETTINGS, Clock, step_ms
from sdm.batch import ConfigurationSet
from sdm.experiments.data import build_sky_dataset
from sdm.experiments.data.synthetic import synthetic_images
from sdm.experiments import noise_runs
from sdm.experiments.network import LOSSES, NetworkSettings, mixed_noise_levels, shift_set, train_network

#: Table 7's training: the default config's research.network.train (16 epochs there; one here) and sizes.
NETWORK_SETTINGS = NetworkSettings(epochs=1, batch_size=16, lr=(("default", 1e-3),), s=2, sigma=0.5, max_points=256)
NETWORK_TRAIN = 3000


def load_author_layer(path: str):
    """The module of the author's ``smap.py`` (its class ``SMap``)."""
    spec = importlib.util.spec_from_file_location("author_smap", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class AuthorStep:
    """One training step of the author's layer on batches of ``data``, as its tutorial trains a shift.

    The input of ``SMap(n=4)`` is ``(B, 4, H, W)`` float32: each pixel holding a point has that point's
    ``k (x + theta)`` (``k = 5 / |z + theta_z|``, the tutorial's scaling) and the mask 1. The loss is the L1
    distance of the layer's output to the target max-pooled to the zoom. ``theta`` ``(1, 3, 1, 1)`` float32
    is the trained parameter.
    """

    def __init__(self, module, data: ConfigurationSet, batch_size: int = 16) -> None:
        camera = data.camera
        matrix = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1.0]], dtype=np.float32)
        self.device = data.device
        self.layer = module.SMap(4, camera.image_height, camera.image_width, matrix, self.device).to(self.device)
        self.data, self.batch_size = data, batch_size
        self.theta = torch.zeros(1, 3, 1, 1, device=self.device, requires_grad=True)

    def images(self, indices: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(B, 3, H, W)`` points and ``(B, 1, H, W)`` mask of configurations ``indices`` (one point a pixel)."""
        batch = self.data.batch(indices)
        height, width = self.data.camera.screen_shape
        xyz = torch.zeros(len(indices), 3, height, width, device=self.device)
        mask = torch.zeros(len(indices), 1, height, width, device=self.device)
        rows, cols = batch.pixels[:, 0], batch.pixels[:, 1]
        xyz[batch.config, :, rows, cols] = batch.points.float()
        mask[batch.config, 0, rows, cols] = 1.0
        return xyz, mask

    def __call__(self, indices: torch.Tensor, zoom: int) -> None:
        xyz, mask = self.images(indices)
        target = self.data.targets.index_select(0, indices).float().unsqueeze(1)
        moved = torch.where(mask > 0.5, xyz + self.theta, torch.zeros_like(xyz))
        scale = torch.where(moved[:, 2:] > 0, 5.0 / (moved[:, 2:].abs() + 1e-7), torch.ones_like(moved[:, 2:]))
        weights = self.layer(torch.cat((scale * moved, mask), 1), target, zoom)
        zoomed = torch.nn.functional.max_pool2d(target, 2 ** zoom) if zoom else target
        loss = (weights - zoomed).abs().sum()
        self.theta.grad = None
        loss.backward()
        with torch.no_grad():
            self.theta -= 1e-9 * self.theta.grad


def author_step_ms(step: AuthorStep, zoom: int, repeats: int) -> float:
    """Median ms of one step of the author's layer at ``zoom`` (the same batches as :func:`bench_sdm.step_ms`)."""
    times = []
    for repeat in range(repeats + 1):
        indices = (torch.arange(step.batch_size) + (repeat * step.batch_size) % (len(step.data) - step.batch_size))
        with Clock(step.device.type) as clock:
            step(indices.to(step.device), zoom)
        if repeat:
            times.append(clock.wall)
    return 1000 * statistics.median(times)


def steps_section(data: ConfigurationSet, author_path: str | None, repeats: int) -> list[dict]:
    """Per-step ms at zoom 4..0: the SDM layer, and the author's layer where its path is given."""
    author = AuthorStep(load_author_layer(author_path), data) if author_path else None
    rows = []
    print(f"{'zoom':>4} {'SDM ms/step':>12} {'author ms/step':>15} {'author/SDM':>11}")
    for zoom in range(4, -1, -1):
        ours = step_ms(data, "fast", zoom, repeats)
        theirs = author_step_ms(author, zoom, repeats) if author else float("nan")
        rows.append({"zoom": zoom, "sdm_ms": ours, "author_ms": theirs, "ratio": theirs / ours})
        print(f"{zoom:>4} {ours:>12.2f} {theirs:>15.2f} {theirs / ours:>10.2f}x")
    return rows


def table2_section(data: ConfigurationSet, runs_per_level: int, group_sizes: list[int],
                   noise_levels: list[int] = TABLE2_LEVELS) -> dict:
    """Table 2's runs at ``levels`` on the GPU at each group size; their theta against the CPU's (the compiled
    kernel, default groups)."""
    out = {"runs": len(noise_levels) * runs_per_level, "levels": list(noise_levels), "groups": []}
    theta_gpu = None
    for group_size in group_sizes:
        with Clock("cuda") as clock:
            frames = [noise_runs(data, noise_level, range(runs_per_level), TABLE2_SETTINGS, group_size=group_size)
                      for noise_level in noise_levels]
        theta_gpu = np.concatenate([frame[["a", "b"]].to_numpy() for frame in frames])
        out["groups"].append({"group_size": group_size, "wall_s": clock.wall, "cpu_s": clock.cpu})
        print(f"{out['runs']} Table 2 runs (levels {list(noise_levels)}) on the GPU, groups of {group_size}: "
              f"{clock.wall:.2f} s wall, {1000 * clock.wall / out['runs']:.0f} ms a run (all 300: target at most 5 s)")
    cpu = data.to("cpu")
    with Clock() as clock:
        frames = [noise_runs(cpu, noise_level, range(runs_per_level), TABLE2_SETTINGS) for noise_level in noise_levels]
    theta_cpu = np.concatenate([frame[["a", "b"]].to_numpy() for frame in frames])
    out |= {"cpu_wall_s": clock.wall, "cpu_s": clock.cpu, "max_abs_diff_m": float(np.abs(theta_gpu - theta_cpu).max())}
    print(f"the same runs on the CPU (compiled kernel, 1 thread): {clock.wall:.2f} s wall; largest |theta GPU - "
          f"theta CPU|: {out['max_abs_diff_m']:.3g} m")
    return out


def network_section(data: ConfigurationSet) -> list[dict]:
    """One epoch of Table 7's training per loss, on the GPU and on the CPU (one thread)."""
    noise_levels = mixed_noise_levels(NETWORK_TRAIN + 16, (0, 1, 2, 3, 4), seed=1)
    sets = {}
    for device in ("cuda", "cpu"):
        whole = shift_set(data.subset(range(NETWORK_TRAIN + 16)).to(device), 0, noise_levels)
        sets[device] = (whole.subset(range(NETWORK_TRAIN)), whole.subset(range(NETWORK_TRAIN, NETWORK_TRAIN + 16)))
    warm_up = sets["cuda"][0].subset(range(32))
    for loss in LOSSES:  # the device's first calls (cuDNN's set-up, kernels loaded) are not any loss's epoch
        train_network(loss, warm_up, warm_up, NETWORK_SETTINGS)
    rows = []
    print(f"{'loss':>16} {'GPU s/epoch':>12} {'CPU s/epoch':>12} {'CPU/GPU':>8}")
    for loss in LOSSES:
        row = {"loss": loss}
        for device in ("cuda", "cpu"):
            train, dev = sets[device]
            try:
                with Clock(device) as clock:
                    trained = train_network(loss, train, dev, NETWORK_SETTINGS)
                row[f"{device}_s"] = clock.wall
                row[f"{device}_dev_mean_m"] = float(trained.curve["dev_mean_m"].iloc[-1])
            except Exception as error:  # a loss that fails on one device is reported, the others still timed
                row[f"{device}_s"] = float("nan")
                row[f"{device}_error"] = f"{type(error).__name__}: {error}"
                print(f"  {loss} on {device}: {row[f'{device}_error']}")
        row["ratio"] = row["cpu_s"] / row["cuda_s"]
        rows.append(row)
        print(f"{loss:>16} {row['cuda_s']:>12.2f} {row['cpu_s']:>12.2f} {row['ratio']:>7.1f}x")
    return rows


def markdown(figures: dict) -> str:
    """The figures as the Markdown tables of a page."""
    lines = [f"Device: {figures['device']}; torch {figures['torch']}; host CPU: {figures['cpu']}.", ""]
    if figures.get("steps"):
        lines += ["ms per training step (16 configurations, forward, backward and update), median:", "",
                  "| zoom | SDM (this layer) | the author's layer | author / SDM |", "|---:|---:|---:|---:|"]
        lines += [f"| {r['zoom']} | {r['sdm_ms']:.2f} | {r['author_ms']:.2f} | {r['ratio']:.2f}x |"
                  for r in figures["steps"]]
        lines.append("")
    if figures.get("table2"):
        t2 = figures["table2"]
        lines += [f"{t2['runs']} Table 2 runs at noise levels {t2['levels']} (512 configurations, n_epoch 2, lr 1e-4):",
                  "",
                  "| where | runs packed per call | wall s |", "|---|---:|---:|"]
        lines += [f"| GPU | {g['group_size']} | {g['wall_s']:.2f} |" for g in t2["groups"]]
        lines += [f"| CPU, compiled kernel, 1 thread | 4 | {t2['cpu_wall_s']:.2f} |", "",
                  f"Largest difference of a run's theta, GPU against CPU: {t2['max_abs_diff_m']:.3g} m.", ""]
    if figures.get("network"):
        lines += ["One epoch of Table 7's training (3,000 configurations, batch 16, 187 steps, zoom 0), wall s:", "",
                  "| loss | GPU | CPU, 1 thread | CPU / GPU |", "|---|---:|---:|---:|"]
        lines += [f"| {r['loss']} | {r['cuda_s']:.2f} | {r['cpu_s']:.2f} | {r['ratio']:.1f}x |"
                  for r in figures["network"]]
        lines.append("")
    if figures.get("errors"):
        lines += ["Sections that failed:", ""] + [f"- {name}: {text}" for name, text in figures["errors"].items()]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--author-layer", help="the author's smap/smap.py, timed beside the SDM layer")
    parser.add_argument("--step-repeats", type=int, default=30)
    parser.add_argument("--table2-runs", type=int, default=60, help="runs per noise level (0: skip)")
    parser.add_argument("--table2-levels", type=int, nargs="+", default=list(TABLE2_LEVELS))
    parser.add_argument("--group-sizes", type=int, nargs="+", default=[60])
    parser.add_argument("--skip-network", action="store_true")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", help="write the figures to this JSON file")
    parser.add_argument("--markdown", help="write the figures as Markdown tables to this file")
    args = parser.parse_args()
    if not torch.cuda.is_available():
        print("no CUDA device: the GPU section is skipped")
        return
    torch.set_num_threads(1)
    figures = {"device": torch.cuda.get_device_name(), "torch": torch.__version__,
               "cpu": platform.processor() or platform.machine(), "errors": {}}
    print(f"GPU section on {figures['device']} (torch {figures['torch']})")
    began = time.perf_counter()
    configurations = build_sky_dataset(synthetic_images(5277, seed=args.seed), n_sample=4248, seed=args.seed,
                                       progress=False)
    print(f"the default Sky data set built in {time.perf_counter() - began:.1f} s")
    everything = ConfigurationSet.from_configurations(configurations)
    table2_set = everything.subset(range(512)).to("cuda")
    sections = [("steps", lambda: steps_section(table2_set, args.author_layer, args.step_repeats))]
    if args.table2_runs:
        sections.append(("table2", lambda: table2_section(table2_set, args.table2_runs, args.group_sizes,
                                                          args.table2_levels)))
    if not args.skip_network:
        sections.insert(1, ("network", lambda: network_section(everything)))
    for name, section in sections:
        print(f"\n-- {name}")
        try:
            figures[name] = section()
        except Exception as error:  # report the section's failure and go on with the others
            traceback.print_exc()
            figures["errors"][name] = f"{type(error).__name__}: {error}"
        if args.json:  # after every section: a run stopped at its time limit keeps what it measured
            with open(args.json, "w") as handle:
                json.dump(figures, handle, indent=2)
        if args.markdown:
            with open(args.markdown, "w") as handle:
                handle.write(markdown(figures))


if __name__ == "__main__":
    main()

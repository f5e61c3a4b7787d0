"""A car's exact-match set of shifts per screen scale, and what each disc rule costs (docs/method/objects.md).

    PYTHONPATH=src python benchmarks/studies/objects_identifiability.py SKY SPLIT [--config config.yaml] [--scales 1 2 4 8]
        [--first 8] [--configurations 16] [--runs 1] [--seed 1000] [--disc pixels] [--out FILE]

Protocol: training configurations ``first .. first + configurations - 1`` of SKY and SPLIT (Table 6 takes the
first ``research.objects.configurations``, so none of these is in a table), rebuilt on the screen scaled ``scale``
times (:func:`sdm.sky.rescaled_configuration`, disc rule ``--disc``). One shift per car drawn from
``research.objects.truth`` with ``run_seed(--seed, 0, r)`` (Table 6 draws from ``noise.seed``), targets rendered
noise-free. For every car that owns points, :func:`sdm.experiments.identifiability.exact_sets` scans a square of half-width
``0.6 / scale`` m at ``0.01 / scale`` m steps. Per scale it prints the median extent per axis over the cars (and
by depth), the mean distance of a set's points from theta*, theta*'s mean distance from the prior mean (doing
nothing), the share of sets the scan clips, the points per car and the CPU seconds of SDM's paper-rule rows
(:func:`sdm.experiments.objects.sdm_rows` from the prior mean, once per run) per configuration, as a Markdown table.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

import torch
import yaml

import sdm.experiments.objects as objects
from sdm import sharing as S
from sdm.batch import ConfigurationSet
from sdm.experiments.data import SkyFile
from sdm.experiments import run_seed, single_thread
from sdm.experiments.identifiability import exact_sets
from sdm.io import read_json
from sdm.sky import rescaled_configuration, scaled_camera

DEPTHS = ((0.0, 30.0), (30.0, 60.0), (60.0, 1e9))


def measure(configs, camera, scale: int, disc: str, runs: int, seed: int, settings, scan: bool = True) -> dict:
    """One scale: the exact-match sets of every car over ``runs`` draws (unless not ``scan``: NaN), and SDM's rows'
    CPU time."""
    scaled = scaled_camera(camera, scale)
    built = [rescaled_configuration(config, camera, scale, disc) for config in configs]
    data = ConfigurationSet.from_configurations(built, scaled)
    n_cars = torch.tensor([int(config.centres.shape[0]) for config in built], dtype=torch.int64)
    sharing = S.sharing("car", data, n_cars=n_cars)
    units = S.units(data, sharing.param_index, sharing.n_rows)
    depth = torch.zeros(len(units), dtype=torch.float64).index_reduce_(
        0, units.point_unit, data.points[:, 2], "amax", include_self=False)
    extents, distances, prior, clipped, depths, sdm_s, scan_s = [], [], [], [], [], 0.0, 0.0
    for run in range(runs):
        own_seed = run_seed(seed, 0, run)
        theta = S.draw_truth(sharing, own_seed, settings.truth)
        truth = S.unit_totals(theta, units)
        clean = data.with_targets(S.render_targets(data, theta, sharing.param_index))
        began = time.process_time()
        sets = exact_sets(clean, units, truth, reach=0.6 / scale, step=0.01 / scale, scan=None if scan else [])
        scan_s += time.process_time() - began
        extents.append(sets.extent)
        distances.append(sets.distance)
        clipped.append(sets.clipped)
        depths.append(depth)
        prior.append((truth - objects.prior_totals(settings.truth, len(units))).norm(dim=1))
        prior_start = (objects.prior_totals(settings.truth, 1)[0], 0.0)
        _, _, seconds, _ = objects.sdm_rows(data, clean.targets, sharing, own_seed, settings, None, prior_start)
        sdm_s += seconds
    extent = torch.cat(extents)
    depth = torch.cat(depths) if scan else torch.zeros(0, dtype=torch.float64)
    nan = float("nan")
    row = {"scale": scale, "screen": f"{scaled.screen_height} x {scaled.screen_width}", "cars": len(units) * runs,
           "a": float(extent[:, 0].median()) if scan else nan, "b": float(extent[:, 1].median()) if scan else nan}
    for low, high in DEPTHS:
        near = (depth >= low) & (depth < high)
        row[f"{low:.0f}"] = (float(extent[near, 0].median()), float(extent[near, 1].median()), int(near.sum())) \
            if bool(near.any()) else None
    row |= {"set_distance": float(torch.cat(distances).mean()) if scan else nan,
            "prior": float(torch.cat(prior).mean()),
            "clipped": float(torch.cat(clipped).to(torch.float64).mean()) if scan else nan,
            "points_per_car": data.points.shape[0] / max(len(units), 1), "sdm_ms": 1e3 * sdm_s / runs / len(data),
            "scan_s": scan_s}
    return row


def markdown(rows, spread: float, disc: str) -> str:
    """The measured rows as a Markdown table (1e-3 m)."""
    lines = [f"Disc rule: {disc}. theta*'s spread per axis {1e3 * spread:.0f}e-3 m; a quarter of it "
             f"{250 * spread:.1f}e-3 m.", "",
             "| scale | screen | cars | median extent a x b | < 30 m | 30-60 m | >= 60 m | set's mean distance "
             "| doing nothing | clipped | points per car | SDM rows ms / config |",
             "|---:|:---:|---:|:---:|:---:|:---:|:---:|---:|---:|---:|---:|---:|"]
    for row in rows:
        bins = []
        for low, _ in DEPTHS:
            found = row[f"{low:.0f}"]
            bins.append("-" if found is None else f"{1e3 * found[0]:.1f} x {1e3 * found[1]:.1f} ({found[2]})")
        lines.append(f"| {row['scale']} | {row['screen']} | {row['cars']} | {1e3 * row['a']:.1f} x "
                     f"{1e3 * row['b']:.1f} | " + " | ".join(bins) + f" | {1e3 * row['set_distance']:.1f} | "
                     f"{1e3 * row['prior']:.1f} | {100 * row['clipped']:.0f} % | {row['points_per_car']:.0f} | "
                     f"{row['sdm_ms']:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sky")
    parser.add_argument("split")
    parser.add_argument("--config", default="config.yaml")
    parser.add_argument("--scales", type=int, nargs="+", default=[1, 2, 4, 8])
    parser.add_argument("--first", type=int, default=8)
    parser.add_argument("--configurations", type=int, default=16)
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--disc", default="pixels")
    parser.add_argument("--out", default=None)
    parser.add_argument("--no-scan", action="store_true", help="the costs alone: no exact-match sets")
    args = parser.parse_args(argv)
    single_thread(1)
    config = yaml.safe_load(open(args.config))
    section, training = config["research"]["objects"], config["train"]
    settings = objects.settings_from_sections(section, training)
    settings = replace(settings, rows=replace(settings.rows, seed=0))
    chosen = read_json(args.split)["train"][args.first:args.first + args.configurations]
    with SkyFile(args.sky) as sky:
        configs = [sky[i] for i in chosen]
        camera = sky.camera
    rows = []
    for scale in args.scales:
        began, wall = time.process_time(), time.perf_counter()
        rows.append(measure(configs, camera, scale, args.disc, args.runs, args.seed, settings, not args.no_scan))
        print(f"scale {scale}: {time.process_time() - began:.1f} CPU s, {time.perf_counter() - wall:.1f} s wall "
              f"(the scan {rows[-1]['scan_s']:.1f} CPU s)", file=sys.stderr, flush=True)
    text = markdown(rows, float(section["truth"]["car_sd"]), args.disc)
    print(text)
    if args.out:
        with open(args.out, "w") as out:
            out.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Table 6's runs on configurations and seeds no table holds, at a screen scale (docs/method/objects.md).

    PYTHONPATH=src python benchmarks/studies/objects_dev.py SKY SPLIT [--config config.yaml] [--scale 1] [--disc pixels]
        [--sharing car] [--levels 0 2] [--runs 3] [--first 8] [--configurations 8] [--seed 1000]
        [--methods sdm_paper sdm_schedule cmaes cmaes_car floor] [--sigma0 S] [--penalty W] [--rows LR N_EPOCH S]
        [--gate G] [--first-zoom {s,prior}] [--tails]

Protocol: :func:`sdm.experiments.objects.objects_runs` with the config's ``research.objects`` settings on training
configurations ``first .. first + configurations - 1`` (Table 6 takes the first ones), rebuilt on the screen
scaled ``--scale`` times (:func:`sdm.sky.rescaled_configuration`), runs ``0 .. runs - 1`` seeded from ``--seed``
(Table 6 from ``noise.seed``). ``--sigma0`` replaces every search's initial step (metres), ``--penalty`` the regularised
search's weight, ``--rows`` SDM's rows' schedule, ``--first-zoom`` where its rows start
(:attr:`sdm.experiments.objects.ObjectsSettings.first_zoom`), ``--gate`` the prior gate (standard deviations) scored
beside every method. Prints Table 6's rows
(:func:`sdm.experiments.report.objects.table6`: each method's mean against its start's, 1e-3 m, as it is and after the prior
gate) and the CPU seconds; with
``--tails``, per level and method, where its mean comes from: its median over its start's median, the share of units
that end farther than their start, the mean of the others over the start's mean, and the share of the method's summed
distance those farther units carry.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

import pandas as pd
import torch
import yaml

import sdm.experiments.objects as objects
import sdm.sharing as S
from sdm.batch import ConfigurationSet
from sdm.experiments.data import SkyFile
from sdm.experiments import single_thread
from sdm.io import read_json
from sdm.experiments.report.objects import table6
from sdm.sky import rescaled_configuration, scaled_camera


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sky")
    parser.add_argument("split")
    parser.add_argument("--config", default="config.yaml")
    parser.add_argument("--scale", type=int, default=1)
    parser.add_argument("--disc", default="pixels")
    parser.add_argument("--sharing", default="car", choices=S.ROW_SHARINGS)
    parser.add_argument("--levels", type=int, nargs="+", default=[0, 2])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--first", type=int, default=8)
    parser.add_argument("--configurations", type=int, default=8)
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--methods", nargs="+", default=["sdm_paper", "sdm_schedule", "cmaes", "cmaes_car", "floor"])
    parser.add_argument("--sigma0", type=float, default=None)
    parser.add_argument("--penalty", type=float, default=None)
    parser.add_argument("--rows", type=float, nargs=3, default=None, metavar=("LR", "N_EPOCH", "S"),
                        help="SDM's rows' rate, epochs per zoom and coarsest zoom")
    parser.add_argument("--gate", type=float, default=None, help="the prior gate, standard deviations")
    parser.add_argument("--first-zoom", choices=objects.FIRST_ZOOMS, default=None,
                        help="where SDM's rows start training (default: the config's)")
    parser.add_argument("--tails", action="store_true", help="where each mean comes from (the module's text)")
    args = parser.parse_args(argv)
    single_thread(1)
    config = yaml.safe_load(open(args.config))
    section, training = config["research"]["objects"], config["train"]
    settings = objects.settings_from_sections(section, training)
    if args.sigma0 is not None:  # every search's initial step
        settings = replace(settings, cmaes=replace(settings.cmaes, sigma0=args.sigma0), car_sigma0=args.sigma0)
    if args.penalty is not None:
        settings = replace(settings, cmaes=replace(settings.cmaes, penalty=args.penalty))
    if args.rows is not None:
        lr, n_epoch, s = args.rows
        settings = replace(settings, rows=replace(settings.rows, lr=lr, n_epoch=int(n_epoch), s=int(s)))
    if args.gate is not None:
        settings = replace(settings, gate=args.gate)
    if args.first_zoom is not None:
        settings = replace(settings, first_zoom=args.first_zoom)
    chosen = read_json(args.split)["train"][args.first:args.first + args.configurations]
    with SkyFile(args.sky) as sky:
        configs = [sky[i] for i in chosen]
        camera = sky.camera
    configs = [rescaled_configuration(config, camera, args.scale, args.disc) for config in configs]
    data = ConfigurationSet.from_configurations(configs, scaled_camera(camera, args.scale))
    n_cars = torch.tensor([int(config.centres.shape[0]) for config in configs], dtype=torch.int64)
    frames = []
    for noise_level in args.levels:
        began, wall = time.process_time(), time.perf_counter()
        frames.append(objects.objects_runs(data, args.sharing, noise_level, list(range(args.runs)), args.seed, settings,
                                           n_cars=n_cars, methods=args.methods))
        print(f"level {noise_level}: {time.process_time() - began:.1f} CPU s, {time.perf_counter() - wall:.1f} s wall",
              file=sys.stderr, flush=True)
    table = table6(frames)
    shown = table.assign(mean=1e3 * table["mean_m"], start=1e3 * table["start_m"], gated=1e3 * table["gated_m"])
    print(f"scale {args.scale} ({args.disc}), {args.sharing}, {args.runs} runs of {len(data)} configurations, "
          f"sigma0 {settings.cmaes.sigma0}, penalty {settings.cmaes.penalty}, rows {settings.rows.lr} "
          f"x {settings.rows.n_epoch} epochs, s {settings.rows.s}, first zoom {settings.first_zoom}, "
          f"gate {settings.gate}")
    print(shown[["noise_level", "method", "units", "mean", "start", "of_start", "closer", "gated", "gated_of_start",
                 "cpu_ms"]]
          .to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    if args.tails:
        print(tails(pd.concat(frames, ignore_index=True)).to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    return 0


def tails(records: pd.DataFrame) -> pd.DataFrame:
    """Per (level, method) of :func:`sdm.experiments.objects.objects_runs`' records: ``median_of_start`` (its median distance over
    its start's median), ``farther`` (the share of units ending farther than their start), ``rest_of_start`` (the
    mean of the other units over the start's mean on all units) and ``farther_share`` (the share of its summed
    distance the farther units carry)."""
    rows = []
    scored = records[~records["method"].isin(["hidden", "start", "prior"])]
    for (noise_level, method), own in scored.groupby(["noise_level", "method"], sort=False):
        far = own["distance"] > own["start"]
        rows.append({"noise_level": noise_level, "method": method, "units": len(own),
                     "median_of_start": own["distance"].median() / own["start"].median(),
                     "farther": far.mean(), "rest_of_start": own.loc[~far, "distance"].mean() / own["start"].mean(),
                     "farther_share": own.loc[far, "distance"].sum() / own["distance"].sum()})
    return pd.DataFrame(rows)


if __name__ == "__main__":
    sys.exit(main())

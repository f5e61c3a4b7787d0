"""Table 2 per gradient rule, and each rule's flow at theta* (docs/method/rules.md).

    PYTHONPATH=src python benchmarks/studies/flow_rules.py SKY.bin SPLIT.json [--rules paper,closed_centred_r1] [--runs 20] [--levels 0,1,2,3,4]

On another run's data (the real sample: results/apollocar3d-sample/...), ``--best BEST.json`` trains with that
run's Table 1 choice instead of the default's, and ``--cmaes TUNING.csv`` adds CMA-ES (that run's tuned cell) on
the same runs, with each rule's ratio to it. ``--pass-steps K``, ``--refine-rate-from K``, ``--first-width W`` and
``--last-width W`` (metres) change the refined schedules' :class:`sdm.train.Refinement` (its passes' kernel
half-widths narrow by halves from ``first_width`` to ``last_width``); ``--crossing-width W`` sets both, one width
on every pass. ``--pass-widths W0,W1,...`` and ``--pass-rates F0,F1,...`` are measurement knobs, not settings of the
library: each pass's width (metres), and each pass's rate as a factor on the first pass's rate
(``1,0.5,0.25,0.125``: the halving of :meth:`Refinement.rates`), in place of :attr:`Refinement.widths` and
:meth:`Refinement.rates`.

For every rule: Table 2's protocol (noise levels, runs r = 0..R-1 with the noisy
targets and shuffling of ``run_seed(0, level, r)``, the tuned settings: 2 epochs,
lr 1e-4, s 4, batches of 16, lr decay 0.5), the mean and standard deviation of the
distance of the final theta to theta* (metres); then the summed flow at theta*
per training configuration at zoom 0 on run 0's noisy targets of each level
(zero at level 0 means theta* is a fixed point; near zero under noise means an
unbiased rule). The paper's rule is the default and gives today's numbers.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace

import pandas as pd
import torch

from sdm import FLOW_RULES
from sdm.mapping.research_rules import RESEARCH_RULES
from sdm.experiments import flow_at_true_shift, load_split, noise_runs, settings_for
from sdm.train import Refinement, parse_schedule

TUNED = dict(n_epoch=2, lr=1e-4, s=4, batch_size=16, lr_decay=0.5, seed=0)
#: Table 2 of the paper, mean distance (metres) per noise level 1..4; the bar is half of it ("half the paper's mean").
PAPER_TABLE2 = {1: 16.3e-3, 2: 25.0e-3, 3: 35.4e-3, 4: 40.1e-3}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sky")
    parser.add_argument("split")
    parser.add_argument("--rules", default="paper,closed_centred_r1",
                        help=f"comma-separated, of {','.join(FLOW_RULES)} or the experiments {','.join(RESEARCH_RULES)}; "
                             "RULE+REFINE:E trains RULE, then E refinement passes with REFINE (sdm.train.Refinement)")
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--first-run", type=int, default=0,
                        help="runs FIRST..FIRST+runs-1 (60 and up: runs no table of the default run holds)")
    parser.add_argument("--refine-rate-from", type=int, default=None,
                        help="Refinement.rate_from of the refined schedules (default: the class's)")
    parser.add_argument("--pass-steps", type=int, default=None,
                        help="Refinement.pass_steps of the refined schedules (default: the class's)")
    parser.add_argument("--best", help="a run's results/tuning/best.json: train with its n_epoch and lr")
    parser.add_argument("--cmaes", help="a run's results/baselines/tuning_cmaes.csv: CMA-ES on the same runs")
    parser.add_argument("--first-width", type=float, default=None,
                        help="Refinement.first_width of the refined schedules, metres (default: the class's)")
    parser.add_argument("--last-width", type=float, default=None,
                        help="Refinement.last_width of the refined schedules, metres (default: the class's)")
    parser.add_argument("--crossing-width", type=float, default=None,
                        help="one kernel half-width on every pass of the refined schedules: first and last width")
    parser.add_argument("--pass-widths", help="each pass's kernel half-width, metres, comma-separated")
    parser.add_argument("--pass-rates", help="each pass's rate over the first pass's, comma-separated")
    parser.add_argument("--levels", default="0,1,2,3,4")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--no-flow", action="store_true", help="skip the flow at theta*")
    parser.add_argument("--csv", help="write the per-run rows here")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    train_set, _, camera = load_split(args.sky, json.load(open(args.split)))
    noise_levels = [int(v) for v in args.levels.split(",")]
    best = json.load(open(args.best)) if args.best else {}
    settings = settings_for(**(TUNED | {key: best[key] for key in ("n_epoch", "lr") if key in best}))
    print(f"# {len(train_set)} training configurations; n_epoch {settings.n_epoch}, lr {settings.lr:g}",
          file=sys.stderr)
    rows, table, flows = [], [], []
    for rule in args.rules.split(","):
        start, cpu = time.time(), time.process_time()
        base, refine = parse_schedule(rule)
        if refine is not None and args.refine_rate_from is not None:
            refine = replace(refine, rate_from=args.refine_rate_from)
        if refine is not None and args.pass_steps is not None:
            refine = replace(refine, pass_steps=args.pass_steps)
        widths = {"first_width": args.first_width, "last_width": args.last_width}
        if args.crossing_width is not None:
            widths = {"first_width": args.crossing_width, "last_width": args.crossing_width}
        if refine is not None:
            refine = replace(refine, **{key: value for key, value in widths.items() if value is not None})
            refine = _given(refine, args.pass_widths, args.pass_rates, settings)
            rates = [f"{rate / refine.rates(settings)[0]:.3g}" for rate in refine.rates(settings)]
            print(f"# {rule}: kernel half-widths per pass {refine.widths} m, rates over the first pass's {rates}",
                  file=sys.stderr)
        for noise_level in noise_levels:
            frame = noise_runs(train_set, noise_level, range(args.first_run, args.first_run + args.runs),
                               replace(settings, rule=base), camera=camera, refine=refine)
            frame.insert(0, "rule", rule)
            rows.append(frame)
            table.append({"rule": rule, "noise_level": noise_level, "mean_mm": 1e3 * frame.distance.mean(),
                          "std_mm": 1e3 * frame.distance.std(), "runs": len(frame),
                          "bar_mm": 0.68 if noise_level == 0 else 0.5e3 * PAPER_TABLE2.get(noise_level, float("nan"))})
        if not args.no_flow:
            flow = flow_at_true_shift(train_set, noise_levels, seed=0, rule=refine.rule if refine else base)
            flow = flow[flow.zoom == 0].drop(columns="zoom")
            flow.insert(0, "rule", rule)
            flows.append(flow)
        print(f"# {rule}: {time.time() - start:.0f} s wall, "
              f"{(time.process_time() - cpu) / max(len(noise_levels) * args.runs, 1):.3f} CPU s per run (with the flow at theta*"
              f" unless --no-flow)", file=sys.stderr, flush=True)
    if args.cmaes:
        from sdm.experiments.baselines import baseline_noise_runs as baseline_runs, best_settings

        chosen = best_settings("cmaes", pd.read_csv(args.cmaes))
        for noise_level in noise_levels:
            frame = baseline_runs("cmaes", train_set, noise_level, range(args.first_run, args.first_run + args.runs), chosen,
                                  settings.seed, camera=camera)
            table.append({"rule": "CMA-ES", "noise_level": noise_level, "mean_mm": 1e3 * frame.distance.mean(),
                          "std_mm": 1e3 * frame.distance.std(), "runs": len(frame),
                          "bar_mm": 0.68 if noise_level == 0 else 0.5e3 * PAPER_TABLE2.get(noise_level, float("nan"))})
    pd.set_option("display.width", 200)
    table = pd.DataFrame(table)
    table["meets_bar"] = table.mean_mm <= table.bar_mm
    print("Table 2 per rule: distance of final theta to theta*, 1e-3 m")
    print(table.pivot(index="rule", columns="noise_level", values="mean_mm").round(2).to_string())
    print(table.round(3).to_string(index=False))
    if args.cmaes:
        means = table.pivot(index="rule", columns="noise_level", values="mean_mm")
        print("\nMean distance / CMA-ES's on the same runs")
        print((means / means.loc["CMA-ES"]).drop(index="CMA-ES").round(2).to_string())
    if flows:
        print("\nFlow at theta* (zoom 0), per training configuration; unmatched share of entered points")
        print(pd.concat(flows).round(3).to_string(index=False))
    if args.csv:
        pd.concat(rows).to_csv(args.csv, index=False)
    return 0


def _given(refine: Refinement, widths: str | None, rates: str | None, settings) -> Refinement:
    """``refine`` with the passes' widths and rate factors given on the command line (a measurement, not a setting
    of the library: :class:`Refinement` defines both from its fields)."""
    if widths is None and rates is None:
        return refine
    width_list = [float(v) for v in widths.split(",")] if widths else refine.widths
    plain = refine.rates(settings)[0]  # the first pass's rate, factor 1
    rate_list = [plain * float(v) for v in rates.split(",")] if rates else refine.rates(settings)
    if not len(width_list) == len(rate_list) == refine.passes:
        raise SystemExit(f"--pass-widths and --pass-rates need one value per pass ({refine.passes})")

    class Given(Refinement):
        @property
        def widths(self):
            return width_list

        def rates(self, _):
            return rate_list

    return Given(**{field: getattr(refine, field) for field in refine.__dataclass_fields__})


if __name__ == "__main__":
    sys.exit(main())

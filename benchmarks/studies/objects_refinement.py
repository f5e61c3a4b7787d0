"""Table 6's SDM rows refined by the schedule's passes at other rates and steps (docs/method/floor.md).

    PYTHONPATH=src python benchmarks/studies/objects_refinement.py SKY SPLIT [--config config.yaml] [--sharing configuration]

Protocol: Table 6's runs (:func:`sdm.experiments.objects.objects_runs`, method ``sdm_schedule`` only) with the settings of the
config's ``research.objects`` section, on the first ``configurations`` training configurations of SKY and SPLIT
(those of ``make run``), runs ``0..runs-1`` of every noise level. Each variant swaps the schedule's
:class:`sdm.train.Refinement` for one with other ``pass_steps`` and, for the damped ones, each pass at
``sqrt(last_width / width)`` of its halving rate (the schedule's former rates). A measurement knob, as
``benchmarks/studies/flow_rules.py --pass-rates``: the library names its schedules, so the variant replaces
``sdm.experiments.objects.parse_schedule`` in this process only. Prints the mean distance per unit (1e-3 m) per level.
"""
from __future__ import annotations

import argparse
import sys

import torch
import yaml

import sdm.experiments.objects as objects
import sdm.sharing as S
from sdm.batch import ConfigurationSet
from sdm.experiments.data import SkyFile
from sdm.experiments import single_thread
from sdm.io import read_json
from sdm.train import Refinement, parse_schedule


class DampedRefinement(Refinement):
    """The schedule's passes with each pass at ``sqrt(last_width / width)`` of its halving rate."""

    def rates(self, settings):
        return [rate * (self.last_width / width) ** 0.5 for rate, width in zip(super().rates(settings), self.widths)]


VARIANTS = {"the schedule (halving, 96 steps)": Refinement(), "halving, 32 steps": Refinement(pass_steps=32),
            "damped, 96 steps": DampedRefinement(pass_steps=96), "damped, 32 steps": DampedRefinement(pass_steps=32)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sky")
    parser.add_argument("split")
    parser.add_argument("--config", default="config.yaml")
    parser.add_argument("--sharing", default="configuration", choices=S.ROW_SHARINGS)
    args = parser.parse_args(argv)
    single_thread(1)
    config = yaml.safe_load(open(args.config))
    section, seed = config["research"]["objects"], int(config["noise"]["seed"])
    chosen = read_json(args.split)["train"][: section["configurations"]]
    with SkyFile(args.sky) as sky:
        configs = [sky[i] for i in chosen]
        camera = sky.camera
    data = ConfigurationSet.from_configurations(configs, camera)
    n_cars = torch.tensor([int(config.centres.shape[0]) for config in configs], dtype=torch.int64)
    training = config["train"]
    settings = objects.settings_from_sections(section, training)
    flow = parse_schedule(section["schedule"])[0]
    print(f"# {args.sharing}: {len(data)} configurations, runs 0-{section['runs'] - 1}, mean distance per unit "
          f"(1e-3 m) at noise levels {section['levels']}")
    for name, refinement in VARIANTS.items():
        objects.parse_schedule = lambda _name, refinement=refinement: (flow, refinement)
        means = []
        for noise_level in section["noise_levels"]:
            runs = objects.objects_runs(data, args.sharing, noise_level, list(range(section["runs"])), seed, settings,
                                        n_cars=n_cars, methods=["sdm_schedule"])
            means.append(1e3 * runs[runs["method"] == "sdm_schedule"]["distance"].mean())
        print(f"{name:34s}" + " / ".join(f"{mean:.2f}" for mean in means), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Do Table 6's far cars end on a neighbour's pixels? A test of the capture hypothesis at scale 12.

At the car level of Table 6 (scale 12), a tenth of the cars' runs end farther than 0.1 m from theta* and make most
of the summed distance. The hypothesis: such a car's points were drawn onto another car's pixels of the target.
This script measures it on the committed per-car records (docs/results/objects/table6_units.csv.gz), with the
configurations of the run that made them (results/sky/sky.bin and results/split/split.json of `make run`).

For each (run, car) of the recommended schedule it moves the car's points by its final shift and by theta*, and
counts the share of the car's pixels that land on another car's target pixels (the others at their theta*). A car
is *on a neighbour* when more than half of its pixels are. It reports that share among the far runs (> 0.1 m) and
the near runs, and, as chance, the same count for the far runs' error turned to 8 other directions around theta*.

Run from the repository root after `make run`: ``.venv/bin/python benchmarks/studies/car_capture.py``.
"""
import math
import sys

import pandas as pd
import torch

from sdm.experiments.data import SkyFile
from sdm.io import read_json
from sdm.representation import screen_pixels
from sdm.sky import rescaled_configuration, scaled_camera, shift_vector

UNITS = "docs/results/objects/table6_units.csv.gz"
SKY, SPLIT = "results/sky/sky.bin", "results/split/split.json"
SCALE, CONFIGURATIONS, METHOD, FAR_M = 12, 4, "sdm_schedule", 0.1


def pixels(points: torch.Tensor, shift: tuple[float, float], camera) -> set[tuple[int, int]]:
    """The screen pixels ``(row, col)`` of ``points`` (``(K, 3)`` metres) moved by ``(a, b, 0)``, as
    :func:`sdm.sky.shifted_target` finds them; off-screen ones dropped."""
    rc, on_screen = screen_pixels(camera.project(points + shift_vector(shift, points)), camera)
    return {tuple(p) for p in rc[on_screen].tolist()}


def on_others(own: set, others: set) -> float:
    return len(own & others) / len(own) if own else float("nan")


def main() -> int:
    units = pd.read_csv(UNITS)
    rows = units[(units["table"] == "runs") & (units["scale"] == SCALE) & (units["sharing"] == "car")
                 & (units["method"] == METHOD)]
    chosen = read_json(SPLIT)["train"][:CONFIGURATIONS]
    with SkyFile(SKY) as file:
        configs, camera = [file[i] for i in chosen], file.camera
    configs = [rescaled_configuration(c, camera, SCALE, "pixels") for c in configs]
    camera = scaled_camera(camera, SCALE)
    points = [c.points(camera) for c in configs]
    for noise_level, frame in rows.groupby("noise_level"):
        records = []
        for (run, config), cars in frame.groupby(["run", "config"]):
            cfg, pts = configs[int(config)], points[int(config)]
            truth = {int(r.car): (r.a_true, r.b_true) for r in cars.itertuples()}
            target = {int(k): pixels(pts[cfg.cars == k], truth[int(k)], camera) for k in truth}
            for r in cars.itertuples():
                k = int(r.car)
                others = set().union(*(target[j] for j in target if j != k))
                own = pts[cfg.cars == k]
                record = {"far": r.distance > FAR_M, "distance": r.distance,
                          "final": on_others(pixels(own, (r.a, r.b), camera), others),
                          "truth": on_others(target[k], others)}
                if record["far"]:
                    da, db = r.a - r.a_true, r.b - r.b_true
                    turned = []
                    for i in range(1, 9):
                        t = 2 * math.pi * i / 9
                        shift = (r.a_true + da * math.cos(t) - db * math.sin(t),
                                 r.b_true + da * math.sin(t) + db * math.cos(t))
                        turned.append(on_others(pixels(own, shift, camera), others) > 0.5)
                    record["chance"] = sum(turned) / len(turned)
                records.append(record)
        table = pd.DataFrame(records)
        far, near = table[table["far"]], table[~table["far"]]
        print(f"noise level {noise_level}: {len(table)} car runs, {len(far)} far (> {FAR_M} m)")
        for name, part in (("far", far), ("near", near)):
            print(f"  {name}: on a neighbour at the final shift {100 * (part['final'] > 0.5).mean():.0f} %, "
                  f"at theta* {100 * (part['truth'] > 0.5).mean():.0f} %; share of pixels on others, mean "
                  f"{part['final'].mean():.2f} (theta*: {part['truth'].mean():.2f})")
        print(f"  chance: the far runs' error turned to 8 other directions lands on a neighbour in "
              f"{100 * far['chance'].mean():.0f} % of turns")
        far_on = far[far["final"] > 0.5]["distance"].sum() / far["distance"].sum()
        print(f"  far runs on a neighbour make {100 * far_on:.0f} % of the far runs' summed distance")
    return 0


if __name__ == "__main__":
    sys.exit(main())

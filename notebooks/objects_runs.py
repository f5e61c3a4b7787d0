# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Table 6: the paired runs of one sharing level at one noise level on one screen
#
# The paper's fundamental problem: each point carries its own shift, and the camera is what shifts points share.
# Here the first configurations of the training split get a shift per configuration, per car, or a camera plus
# a residual per car, drawn from the documented distribution (`sdm.sharing.TruthDistribution`); their targets
# are rendered from those shifts and get Table 2's noise. SDM (the paper's rule and the recommended schedule),
# the black-box searches, the soft-silhouette baseline and the floor all fit the same targets of a run
# (`sdm.experiments.objects.objects_runs`; docs/method/objects.md), on a screen `scale` times finer than the Sky screen
# (`sdm.sky.rescaled_configuration`). On the first run every unit's exact-match set is scanned: what its pixels
# identify (`sdm.experiments.identifiability.exact_sets`). One row per (run, method, unit), each naming its scale; the stage
# `table6` gathers the files.

# %% tags=["parameters"]
sky = "results/sky/sky.bin"  # input
split = "results/split/split.json"  # input
runs_file = "results/research/objects/configuration_level0.csv"  # output: one row per (run, method, unit)
sharing = "configuration"  # the sharing level (sdm.sharing.ROW_SHARINGS)
noise_level = 0  # the noise level
runs = 2  # runs 0..runs-1
configurations = 8  # the first configurations of the training split
truth = {"camera_sd": 0.15, "car_sd": 0.15, "residual_sd": 0.05}
warm = {"lr": 1.0e-4, "n_epoch": 16}
rows = {"lr": 5.0e-3, "n_epoch": 4, "s": 3}
schedule = "closed_centred_r1+group_crossing:4"
cmaes = {"evaluations_per_unknown": 150}
floor = {"evaluations_per_unknown": 50, "restarts": 2}
silhouette = {"lr": 0.1, "sigma": 0.5, "batch_size": 8, "steps": 27}
screen = {"scale": 1, "disc": "pixels"}  # the screen scale (128 x 256 is 1) and the disc rule (sdm.sky)
methods = ["sdm_paper", "sdm_schedule", "cmaes", "cmaes_car", "cmaes_reg", "silhouette", "floor"]  # sdm.experiments.objects.METHODS
gate = 3.5  # the prior gate scored beside every method, prior standard deviations (sdm.experiments.gate.prior_gate)
identifiability = {"reach": 0.6, "step": 0.01}  # the exact-match scan at scale 1, metres (divided by the scale)
seed = 0  # noise.seed: run r at level n draws theta*, its noise and its seeds from (seed, n, r)
s = 4
batch_size = 8
lr_decay = 0.5
threads = 1

# %%
import torch
from IPython.display import display

from sdm.experiments.data import SkyFile
from sdm.experiments import single_thread
from sdm.io import read_json, write_csv
from sdm.batch import ConfigurationSet
from sdm.experiments.objects import objects_runs, settings_from_config
from sdm.sky import rescaled_configuration, scaled_camera

single_thread(threads)
chosen = read_json(split)["train"][:configurations]
with SkyFile(sky) as file:
    configs = [file[i] for i in chosen]
    camera = file.camera
configs = [rescaled_configuration(config, camera, int(screen["scale"]), screen["disc"]) for config in configs]
camera = scaled_camera(camera, int(screen["scale"]))
data = ConfigurationSet.from_configurations(configs, camera)
n_cars = torch.tensor([int(config.centres.shape[0]) for config in configs], dtype=torch.int64)
settings = settings_from_config(truth, warm, rows, schedule, cmaes, floor, silhouette, s, batch_size, lr_decay,
                                gate)
print(f"{len(data)} configurations, {data.points.shape[0]} points, {int(n_cars.sum())} cars on screen")

# %%
scale = int(screen["scale"])
scan = (float(identifiability["reach"]) / scale, float(identifiability["step"]) / scale)
results = objects_runs(data, sharing, noise_level, list(range(runs)), seed, settings, n_cars=n_cars, methods=methods,
                       progress=True, scan=scan)
results.insert(0, "scale", scale)
write_csv(runs_file, results)
scored = results[results["method"] != "hidden"]
display((1000 * scored.groupby("method")[["distance", "cpu_s", "extent_a", "extent_b"]].mean()).round(2))

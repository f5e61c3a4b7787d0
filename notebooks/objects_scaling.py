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
# # Table 6's scaling: error against CPU time with K cars per image
#
# Synthetic images with exactly K visible cars each (`sdm.experiments.data.set_with_cars`), one shift per car drawn as
# Table 6's (`sdm.sharing.TruthDistribution`). SDM's rows train with several epoch budgets and CMA-ES per
# configuration searches with several evaluation budgets, from the same shared start; each gives a point
# (CPU seconds per configuration, distance per car) of its curve (`sdm.experiments.objects.scaling_runs`), with the do-nothing
# references and, on the first run, each car's exact-match set (`sdm.experiments.identifiability.exact_sets`). The images are
# built on the screen `screen["scale"]` times finer than the Sky screen. The stage `table6` draws the curves.

# %% tags=["parameters"]
scaling_file = "results/research/objects/scaling_2.csv"  # output: one row per (run, method, budget)
cars = 2  # K, cars per image
scaling = {"n_images": 4, "seed": 0, "runs": 1, "noise_level": 0, "epochs": [1, 2], "budgets": [10, 30]}
truth = {"camera_sd": 0.15, "car_sd": 0.15, "residual_sd": 0.05}
warm = {"lr": 1.0e-4, "n_epoch": 16}
rows = {"lr": 5.0e-3, "n_epoch": 4, "s": 3}
schedule = "closed_centred_r1+group_crossing:4"
cmaes = {"evaluations_per_unknown": 150}
floor = {"evaluations_per_unknown": 50, "restarts": 2}
silhouette = {"lr": 0.1, "sigma": 0.5, "batch_size": 8, "steps": 27}
screen = {"scale": 1, "disc": "pixels"}  # the screen scale (128 x 256 is 1) and the disc rule (sdm.sky)
gate = 3.5  # the prior gate scored beside every method, prior standard deviations (sdm.experiments.gate.prior_gate)
identifiability = {"reach": 0.6, "step": 0.01}  # the exact-match scan at scale 1, metres (divided by the scale)
seed = 0
s = 4
batch_size = 8
lr_decay = 0.5
threads = 1

# %%
from IPython.display import display

from sdm.camera import APOLLO_CAMERA_5
from sdm.experiments.data import set_with_cars
from sdm.experiments import single_thread
from sdm.io import write_csv
from sdm.experiments.objects import scaling_runs, settings_from_config
from sdm.sky import disc_radius, scaled_camera

single_thread(threads)
data = set_with_cars(int(scaling["n_images"]), cars, int(scaling["seed"]),
                     camera=scaled_camera(APOLLO_CAMERA_5, int(screen["scale"])),
                     n_images_name="research.objects.scaling.n_images", n_cars_name="research.objects.scaling.cars",
                     seed_name="research.objects.scaling.seed",
                     radius=disc_radius(int(screen["scale"]), screen["disc"]))
settings = settings_from_config(truth, warm, rows, schedule, cmaes, floor, silhouette, s, batch_size, lr_decay,
                                gate)
print(f"{len(data)} images with {cars} cars each, {data.points.shape[0]} points")

# %%
scale = int(screen["scale"])
results = scaling_runs(data, cars, int(scaling["noise_level"]), list(range(int(scaling["runs"]))), seed, settings,
                       scaling["epochs"], scaling["budgets"], progress=True,
                       scan=(float(identifiability["reach"]) / scale, float(identifiability["step"]) / scale))
results.insert(0, "scale", scale)
write_csv(scaling_file, results)
display(results.groupby(["method", "budget"])[["mean", "median", "cpu_s"]].mean())

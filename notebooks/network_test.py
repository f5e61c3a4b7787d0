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
# # Table 7: the test set at one noise level
#
# Every trained network (each loss, each training run) on the test configurations, alone (one forward pass) and
# followed by k SDM steps per configuration; beside them, the searches that use no network (CMA-ES per
# configuration and SDM per configuration from zero, Table 6's protocol) and doing nothing (theta*'s mean, the
# training set's mean theta*, the searches' shared start). One row per (method, run, configuration): its error
# and distance to theta* and its CPU seconds (`sdm.experiments.network.test_methods`; docs/method/network.md).

# %% tags=["parameters"]
sky = "results/sky/sky.bin"  # input
weights = []  # input: network_train's weights, in the order of networks
test_file = "results/research/network/test_level0.csv"  # output
sizes = [3000, 500, 748]
seed = 0
noise_levels = [0, 1, 2, 3, 4]
camera_sd = 0.15
noise_level = 0  # this job's noise level
networks = [["sdm_paper", 0]]  # (loss, training run) of each file of weights
refine = {"s": 3, "n_epoch": 1, "lr": 5.0e-3, "rule": "closed_centred_r1", "batch_size": 4}
warm = {"lr": 1.0e-4, "n_epoch": 16}  # research.objects: the searches' settings, as Table 6 runs them
rows = {"lr": 5.0e-3, "n_epoch": 4, "s": 3}
schedule = "closed_centred_r1+group_crossing:4"
cmaes = {"evaluations_per_unknown": 60}
batch_size = 8  # research.objects.batch_size: the searches' mini-batches
s = 4
lr_decay = 0.5
threads = 1

# %%
from IPython.display import display

from sdm.experiments import single_thread
from sdm.io import write_csv
from sdm.experiments.network import load_weights, read_sets, refine_settings, test_methods
from sdm.experiments.objects import search_settings

single_thread(threads)
sets = read_sets(sky, sizes, seed, noise_levels, camera_sd, parts=["train", "test"], test_level=noise_level)
test = sets["test"]
screen = test.data.camera.screen_shape
trained = {(loss, int(run)): load_weights(path, screen) for (loss, run), path in zip(networks, weights)}
searches = search_settings(warm, rows, schedule, cmaes, s, batch_size, lr_decay)
print(f"{len(test)} test configurations at noise level {noise_level}; {len(trained)} networks")

# %%
results = test_methods(test, noise_level, trained, refine_settings(refine, seed), searches, seed,
                       train_mean=sets["train"].truth.mean(0))
write_csv(test_file, results)
display((1000 * results.groupby("method", sort=False)[["distance", "cpu_s"]].mean()).round(3))

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
# # Table 7: where each label-free loss's gradient vanishes on the test set
#
# A network trained with a loss settles, on average, where the loss's mean gradient over its training
# configurations vanishes. Per noise level and loss (SDM's two rules, the soft silhouette), the gradient at each
# test configuration's own theta* (its bias) and its change per metre near theta* (its stiffness) give that
# place's offset from theta*, as `rule_bias` measures it for the shared shift (`sdm.experiments.network.loss_bias`;
# docs/method/network.md).

# %% tags=["parameters"]
sky = "results/sky/sky.bin"  # input
bias_file = "results/research/network/bias.csv"  # output
sizes = [3000, 500, 748]
seed = 0
noise_levels = [0, 1, 2, 3, 4]
camera_sd = 0.15
losses = ["sdm_paper", "sdm_closed_centred_r1", "silhouette"]  # research.network.losses: those of BIAS_LOSSES are measured
train = {"epochs": 16, "per_epoch": 1280, "batch_size": 16, "lr": 3.0e-3, "s": 2, "sigma": 0.5, "max_points": 256}
threads = 1

# %%
import pandas as pd
from IPython.display import display

from sdm.experiments import single_thread
from sdm.io import write_csv
from sdm.experiments.network import BIAS_LOSSES, loss_bias, network_settings, read_sets

single_thread(threads)
settings = network_settings(train, seed)
rows = []
for noise_level in noise_levels:
    test = read_sets(sky, sizes, seed, noise_levels, camera_sd, parts=["test"], test_level=noise_level)["test"]
    rows += [loss_bias(test, noise_level, loss, settings) for loss in BIAS_LOSSES if loss in losses]
bias = pd.DataFrame(rows)
write_csv(bias_file, bias)
display(bias.round(4))

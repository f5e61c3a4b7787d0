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
# # Table 7: a network trained with one loss
#
# A small CNN (`sdm.network.ShiftNet`) reads a configuration's target and its points at zero shift and outputs
# the configuration's own shift. Every loss trains the same architecture from the same initial weights on the
# same shuffles: the SDM layer's loss (its backward is the dynamic gradient flow, no labels), the soft
# silhouette, the 2D Chamfer distance, or the distance to theta* (supervised). After each epoch the dev set's
# distances are recorded (docs/method/network.md).

# %% tags=["parameters"]
sky = "results/sky/sky.bin"  # input
weights = "results/research/network/sdm_paper.pt"  # output: the trained weights (torch state_dict)
curve = "results/research/network/sdm_paper_curve.csv"  # output: one row per epoch
sizes = [3000, 500, 748]  # train, dev, test configurations
seed = 0  # the split, theta*, the noise, the weights and the shuffles
levels = [0, 1, 2, 3, 4]  # noise levels mixed over train and dev
camera_sd = 0.15  # theta*'s spread per axis around the paper's shift, metres
loss = "sdm_paper"  # the training loss (sdm.network.LOSSES)
train = {"epochs": 16, "batch_size": 16, "lr": 1.0e-3, "s": 2, "sigma": 0.5, "max_points": 256}
threads = 1

# %%
from IPython.display import display

from sdm.experiments import single_thread
from sdm.io import write_csv
from sdm.network import network_settings, parameter_count, read_sets, save_weights, train_network

single_thread(threads)
sets = read_sets(sky, sizes, seed, levels, camera_sd)
settings = network_settings(train, seed)
print(f"{len(sets['train'])} training and {len(sets['dev'])} dev configurations")

# %%
trained = train_network(loss, sets["train"], sets["dev"], settings, progress=True)
print(f"{parameter_count(trained.net)} parameters, {trained.seconds:.0f} CPU s of training")
save_weights(trained.net, weights)
write_csv(curve, trained.curve)
display(trained.curve.round(4))

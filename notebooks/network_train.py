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
# # Table 7: a network trained with one loss, in one training run
#
# A small CNN (`sdm.experiments.network.ShiftNet`) reads a configuration's target and its points at zero shift and outputs
# the configuration's own shift. Every loss trains the same architecture on the same configurations; run `run` of
# every loss starts from the same weights and draws the same shuffles and training noise (`training_seed`), so
# the runs pair across losses. The loss is the SDM layer's (its backward is the dynamic gradient flow, no labels),
# the soft silhouette, the 2D Chamfer distance, or the distance to theta* (supervised). After each epoch the dev
# set's distances are recorded (docs/method/network.md).

# %% tags=["parameters"]
sky = "results/sky/sky.bin"  # input
weights = "results/research/network/sdm_paper_run0.pt"  # output: the trained weights (torch state_dict)
curve = "results/research/network/sdm_paper_run0_curve.csv"  # output: one row per epoch
sizes = [3000, 500, 748]  # train, dev, test configurations
seed = 0  # the split, theta*, the noise levels, the dev and test noise; the training runs' seeds
noise_levels = [0, 1, 2, 3, 4]  # noise levels mixed over train and dev
camera_sd = 0.15  # theta*'s spread per axis around the paper's shift, metres
loss = "sdm_paper"  # the training loss (sdm.experiments.network.LOSSES)
run = 0  # the training run: its weights, shuffles and training noise (sdm.experiments.network.training_seed)
train = {"epochs": 16, "per_epoch": 1280, "batch_size": 16, "lr": 3.0e-3, "s": 2, "sigma": 0.5, "max_points": 256}
threads = 1

# %%
from IPython.display import display

from sdm.experiments import single_thread
from sdm.io import write_csv
from sdm.experiments.network import network_settings, parameter_count, read_sets, save_weights, train_network, training_seed
from sdm.sharing import TruthDistribution

single_thread(threads)
run_seed = training_seed(seed, run)
sets = read_sets(sky, sizes, seed, noise_levels, camera_sd, train_noise=run_seed)
settings = network_settings(train, run_seed)
print(f"{len(sets['train'])} training and {len(sets['dev'])} dev configurations; run {run}, seed {run_seed}")

# %%
prior = TruthDistribution(camera_sd=camera_sd)  # theta*'s distribution: the network's output units, no label
trained = train_network(loss, sets["train"], sets["dev"], settings, progress=True, prior=prior)
print(f"{parameter_count(trained.net)} parameters, {trained.seconds:.0f} CPU s of training")
save_weights(trained.net, weights)
write_csv(curve, trained.curve.assign(run=run))
display(trained.curve.round(4))

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
# # Stage 9: the paper's figures
#
# Figure 1: a configuration (E' as a mask, E' as depth, the target L). Figure 2: the SDM forward pass on one
# point (its XY-adjustments and the kernel D). Figure 3: the backward pass on one point (which target
# pixels pull it, and where). Figure 4: a target at noise levels 0-4. Then theta~'s path during training
# with the tuned settings, per zoom level, and the distribution of distances per noise level.
# The drawing code is `sdm.report.figures`; the single-point forward and backward are
# `sdm.mapping.explain_point`.

# %% tags=["parameters"]
sky = "results/sky/sky.bin"
split = "results/split/split.json"
best = "results/tuning/best.json"
best_history = "results/tuning/best_history.csv"  # the tuned run's history
distances = "results/noise/distances.csv"
fig1 = "results/figures/fig1_configuration.png"
fig2 = "results/figures/fig2_forward.png"
fig3 = "results/figures/fig3_backward.png"
fig4 = "results/figures/fig4_noise.png"
theta_path = "results/figures/theta_path.png"
distances_plot = "results/figures/distances.png"
example = 0
noise_seed = 0
levels = [0, 1, 2, 3, 4]
s = 4
shift = [0.517, 0.303]
threads = 1

# %%
import pandas as pd
import torch
from IPython.display import Image, display

from sdm import SDMInputError
from sdm.data import SkyFile
from sdm.experiments import single_thread
from sdm.report import figures
from sdm.report.io import read_json

single_thread(threads)
dataset = SkyFile(sky)
camera = dataset.camera
# The example is counted among the train configurations that have points (an empty one has nothing to draw).
non_empty = [index for index in read_json(split)["train"] if dataset[index].num_points > 0]
if example >= len(non_empty):
    raise SDMInputError(f"config key 'figures.example': only {len(non_empty)} train configurations have points, "
                        f"got example {example}")
configuration = dataset[non_empty[example]]
tuned = read_json(best)


def show(figure, path):
    display(Image(filename=str(figures.save_figure(figure, path))))


show(figures.figure1(configuration, camera), fig1)

# %% [markdown]
# Figure 2: a point of the configuration moved by theta~ = theta* (the true shift), through one SDM level at
# full resolution. Its kernel D weighs the 9 XY-adjustments (the 3D points at its depth that project to the
# centres of the 3x3 neighbouring pixels); as c grows the point lands at the nearest one.

# %%
point, pixel, info = figures.pick_point(configuration, shift, camera)
original = configuration.points(camera)[(configuration.pixels == torch.tensor(pixel)).all(1)][0]
show(figures.figure2(point, original, info, camera=camera), fig2)

# %% [markdown]
# Figure 3: at the start of training (theta~ = 0) a point whose landing pixel is not in the target gets a
# gradient from every target pixel of its 3x3 window: the sign of its offset to each (dynamic gradient flow).

# %%
point, _, info = figures.pick_point(configuration, (0.0, 0.0), camera, matched=False)
show(figures.figure3(point, info), fig3)

# %%
show(figures.figure4(configuration.target, levels, seed=noise_seed), fig4)

# %% [markdown]
# theta~ during the tuned run (the best cell of Table 1), coloured by zoom level.

# %%
history = pd.read_csv(best_history)
show(figures.theta_path_figure(history, shift, title=f"theta~ with n_epoch {tuned['n_epoch']}, lr {tuned['lr']:g}"),
     theta_path)

# %%
show(figures.distances_figure(pd.read_csv(distances)), distances_plot)

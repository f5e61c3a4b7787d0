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
# pixels pull it, and where). Figure 4: a target at noise levels 0-4. They need one configuration of the
# split and nothing trained, so they wait for no tuning or noise run (theta~'s path during the tuned run is
# drawn by the stage `best`, the distances per noise level by `tables`). The drawing code is `sdm.experiments.report.figures`; the single-point forward and backward are
# `sdm.mapping.explain_point`.

# %% tags=["parameters"]
sky = "results/sky/sky.bin"
split = "results/split/split.json"
fig1 = "results/figures/fig1_configuration.png"
fig2 = "results/figures/fig2_forward.png"
fig3 = "results/figures/fig3_backward.png"
fig4 = "results/figures/fig4_noise.png"
example = 0
noise_seed = 0
noise_levels = [0, 1, 2, 3, 4]
s = 4
shift = [0.517, 0.303]
threads = 1

# %%
import torch
from IPython.display import Image, display

from sdm import SDMInputError
from sdm.experiments.data import SkyFile
from sdm.experiments import single_thread
from sdm.experiments.report import figures
from sdm.experiments.report.io import read_json

single_thread(threads)
dataset = SkyFile(sky)
camera = dataset.camera
# The example is counted among the train configurations that have points (an empty one has nothing to draw).
non_empty = [index for index in read_json(split)["train"] if dataset[index].num_points > 0]
if example >= len(non_empty):
    raise SDMInputError(f"config key 'figures.example': only {len(non_empty)} train configurations have points, "
                        f"got example {example}")
configuration = dataset[non_empty[example]]


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
show(figures.figure4(configuration.target, noise_levels, seed=noise_seed), fig4)

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
# # Stage 5: one cell of the tuning grid (Table 1)
#
# Train theta~ = (a~, b~) from (0, 0) on the 512 training configurations with one (n_epoch, learning rate)
# cell: plain SGD on mini-batches of 16, zoom levels s, s-1, ..., 0 with n_epoch passes each, the learning
# rate halving after each level (paper, section 5.1; docs/method/paper.md, Training and evaluation). The cell is scored by the
# dev loss: the mean number of false-positive pixels of the zoom-0 output on the 256 dev configurations.

# %% tags=["parameters"]
sky = "results/sky/sky.bin"  # input
split = "results/split/split.json"  # input
cell = "results/tuning/cell_1_3e-04.json"  # output: the cell's scores
history = "results/tuning/history_1_3e-04.csv"  # output: theta after each step
n_epoch = 1
lr = 3e-4
s = 4
batch_size = 16
lr_decay = 0.5
seed = 0
shift = [0.517, 0.303]
threads = 1

# %%
import matplotlib.pyplot as plt

from sdm.experiments import load_split, settings_for, single_thread, tune_cell
from sdm.experiments.report.figures import theta_path_figure
from sdm.experiments.report.io import read_json, write_csv, write_json

single_thread(threads)
train_set, dev_set, camera = load_split(sky, read_json(split))
settings = settings_for(n_epoch, lr, s, batch_size, lr_decay, seed)
record, frame = tune_cell(train_set, dev_set, settings, shift=shift, camera=camera)
write_json(cell, record)
write_csv(history, frame)
record

# %%
theta_path_figure(frame, shift, title=f"n_epoch {n_epoch}, lr {lr:g}")
plt.show()

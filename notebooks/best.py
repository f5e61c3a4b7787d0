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
# # Stage 6: choose the best cell
#
# Table 1 of the paper: the dev loss of every (n_epoch, learning rate) cell. The cell with the lowest dev
# loss gives the settings of the noise experiments (the paper picks n_epoch = 1, lr = 3e-4). Cells tied on the
# lowest dev loss (the same count of pixels) are told apart by their train loss, the same measure on the
# training configurations, then by the most epochs (SGD steps) and the smaller learning rate; Table 1 marks them (`sdm.experiments.report.tables.best_index`).

# %% tags=["parameters"]
cells = []  # input: one JSON per cell
histories = []  # input: one history per cell, in the same order as cells
grid = "results/tuning/grid.csv"  # output
best = "results/tuning/best.json"  # output
best_history = "results/tuning/best_history.csv"  # output: the chosen cell's history (theta after each step)
theta_path = "results/figures/theta_path.png"  # output: theta~'s path during the chosen cell's run
shift = [0.517, 0.303]  # theta* (a*, b*), metres, marked in the figure
threads = 1

# %%
from pathlib import Path

import pandas as pd

from sdm.experiments.report.io import read_csv, read_json, write_csv, write_json, write_text
from sdm.experiments.report.tables import best_cell, table1_frame

results = [read_json(path) for path in cells]
records = pd.DataFrame.from_records(results)
write_csv(grid, records)
choice = best_cell(records)
chosen = next(i for i, r in enumerate(results) if r["n_epoch"] == choice["n_epoch"] and r["lr"] == choice["lr"])
write_json(best, results[chosen])
write_text(best_history, Path(histories[chosen]).read_text())
table = table1_frame(records)
table

# %%
tied = int(table["tied"].sum()) if "tied" in table else 1
print(f"best: n_epoch {choice['n_epoch']}, lr {choice['lr']:g}, dev loss {choice['dev_loss']:.3f}"
      + (f", tied with {tied - 1} other cell(s) (broken by the train loss, then the most epochs and the smaller lr)" if tied > 1 else ""))

# %% [markdown]
# theta~ during the chosen cell's run, coloured by zoom level.

# %%
from sdm.experiments.report.figures import show_figure, theta_path_figure

tuned = results[chosen]
show_figure(theta_path_figure(read_csv(best_history), shift,
                              title=f"theta~ with n_epoch {tuned['n_epoch']}, lr {tuned['lr']:g}"), theta_path)

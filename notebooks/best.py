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
# loss gives the settings of the noise experiments (the paper picks n_epoch = 1, lr = 3e-4).

# %% tags=["parameters"]
cells = []  # input: one JSON per cell
grid = "results/tuning/grid.csv"  # output
best = "results/tuning/best.json"  # output
threads = 1

# %%
import pandas as pd

from sdm.report.io import read_json, write_csv, write_json
from sdm.report.tables import best_cell, table1_frame

results = [read_json(path) for path in cells]
records = pd.DataFrame.from_records(results)
write_csv(grid, records)
choice = best_cell(records)
write_json(best, next(r for r in results if r["n_epoch"] == choice["n_epoch"] and r["lr"] == choice["lr"]))
table1_frame(records)

# %%
print(f"best: n_epoch {choice['n_epoch']}, lr {choice['lr']:g}, dev loss {choice['dev_loss']:.3f}")

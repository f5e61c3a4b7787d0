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
# # Table 7: SDM inside a network
#
# Gathers `network_test` (one file per noise level) and `network_train`'s learning curves (one per loss and
# training run): per noise level and method, the mean over the runs of the test set's distance to theta*, its
# spread, the paired difference to the SDM-trained network of the same run, and the CPU time per configuration;
# the learning curves; the summary in plain words, a ranking only beyond the runs' spread (`sdm.experiments.report.network`;
# docs/method/network.md).

# %% tags=["parameters"]
test_files = []  # input: network_test's files
curves = []  # input: network_train's learning curves
bias_files = []  # input: network_bias's file (none when no label-free loss with a gradient bias was trained)
table7_csv = "results/tables/table7.csv"  # output
table7_md = "results/tables/table7.md"  # output
table7_tex = "results/tables/table7.tex"  # output
table7_html = "results/tables/table7.html"  # output
table7_summary = "results/tables/table7_summary.md"  # output
table7_verdict = "results/tables/table7_verdict.json"  # output: the verdict's facts of Table 7
table7_curves = "results/tables/table7_curves.csv"  # output: every learning curve, one row per loss, run and epoch
figure = "results/figures/network_curves.png"  # output
refine = {"s": 3, "n_epoch": 1, "lr": 5.0e-3, "rule": "closed_centred_r1", "batch_size": 4}
train = {"epochs": 16, "per_epoch": 1280}
sizes = [3000, 500, 748]
threads = 1

# %%
from pathlib import Path

import pandas as pd
from IPython.display import Image, Markdown, display

from sdm.io import write_csv, write_json, write_text
from sdm.experiments.report.io import read_csv
from sdm.experiments.network import refine_settings, refine_steps
from sdm.experiments.report import network as report

frames = [read_csv(path) for path in test_files]
curve_frames = [read_csv(path) for path in curves]
table = report.table7(frames, curve_frames)
report.write_table7(table, Path(table7_csv).with_suffix(""))
display(Markdown(Path(table7_md).read_text()))

# %%
bias = read_csv(bias_files[0]) if bias_files else None
summary = report.table7_summary(table, refine_steps(refine_settings(refine, seed=0)), train, int(sizes[0]), bias)
write_text(table7_summary, summary)
write_json(table7_verdict, report.verdict_facts(table))  # what the README's verdict says of Table 7, as data
display(Markdown(summary))

# %%
write_csv(table7_curves, pd.concat(curve_frames, ignore_index=True))
report.plot_curves(curve_frames, figure)
display(Image(figure))

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
# # Stage 8: Tables 1 and 2
#
# Table 1: dev loss over the tuning grid. Table 2: per noise level, mean, std and quartiles of the distances
# ||theta~ - theta*|| (1e-3 m), and "Avg. Dist.", the 3D displacement the pixel noise stands for at the Sky
# data's mean target depth (`sdm.sky.noise_displacement`; docs/method/paper.md, Experiments). Each table is written
# as CSV, Markdown and LaTeX with the paper's values beside ours.

# %% tags=["parameters"]
grid = "results/tuning/grid.csv"
best = "results/tuning/best.json"
stats = "results/sky/stats.json"
chunks = []  # input: the noise chunks
distances = "results/noise/distances.csv"  # output: every run
distances_plot = "results/figures/distances.png"  # output: the distances per noise level beside the paper's
table1_csv = "results/tables/table1.csv"
table1_md = "results/tables/table1.md"
table1_tex = "results/tables/table1.tex"
table1_html = "results/tables/table1.html"  # the outputs are written beside table1_csv, same stem
table2_csv = "results/tables/table2.csv"
table2_md = "results/tables/table2.md"
table2_tex = "results/tables/table2.tex"
table2_html = "results/tables/table2.html"
noise_levels = [0, 1, 2, 3, 4]
runs = 60
threads = 1

# %%
from pathlib import Path

import pandas as pd
from IPython.display import Markdown, display

from sdm.experiments.data.stats import avg_dist_mm
from sdm.experiments.report.io import read_csv, read_json, write_csv
from sdm.experiments.report.tables import TABLE1_FORMAT, TABLE2_FORMAT, table1_frame, table2_frame, to_markdown, write_table

all_runs = pd.concat([read_csv(path) for path in chunks]).sort_values(["noise_level", "run"]).reset_index(drop=True)
expected = {(noise_level, run) for noise_level in noise_levels for run in range(runs)}
found = set(zip(all_runs["noise_level"], all_runs["run"]))
assert found == expected, f"missing runs: {sorted(expected - found)[:10]}, unexpected: {sorted(found - expected)[:10]}"
write_csv(distances, all_runs)

# %%
table1 = table1_frame(read_csv(grid))
written = write_table(table1, Path(table1_csv).with_suffix(""), TABLE1_FORMAT)
assert {str(path) for path in written} == {table1_csv, table1_md, table1_tex, table1_html}, written
display(Markdown(to_markdown(table1, TABLE1_FORMAT)))

# %%
depth = read_json(stats)["target_mean_depth"]
table2 = table2_frame(all_runs, avg_dist_mm(depth, noise_levels=[noise_level for noise_level in noise_levels if noise_level > 0]))
written = write_table(table2, Path(table2_csv).with_suffix(""), TABLE2_FORMAT)
assert {str(path) for path in written} == {table2_csv, table2_md, table2_tex, table2_html}, written
print(f"mean target depth {depth:.2f} m")
display(Markdown(to_markdown(table2, TABLE2_FORMAT)))

# %% [markdown]
# Table 2's runs, per noise level, beside the paper's mean and quartiles.

# %%
from sdm.experiments.report.figures import distances_figure, show_figure

show_figure(distances_figure(read_csv(distances)), distances_plot)

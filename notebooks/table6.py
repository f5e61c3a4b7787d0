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
# # Table 6: parameters attached to points
#
# Gathers `objects_runs` (one file per sharing level and noise level) and `objects_scaling` (one file per K cars
# per image): per sharing level, noise level and method, the distance per unit to theta* (mean, median, Q3) and
# the CPU time per configuration, Table 2's runs quoted as the shared level; the figure of the means; the
# scaling figure (error against CPU time, one curve per K); the summary in plain words
# (`sdm.report.objects`; docs/method/objects.md).

# %% tags=["parameters"]
runs_files = []  # input: objects_runs' files
scaling_files = []  # input: objects_scaling's files
table2_distances = "results/noise/distances.csv"  # input: Table 2's runs (the shared level)
table6_csv = "results/tables/table6.csv"  # output
table6_md = "results/tables/table6.md"  # output
table6_tex = "results/tables/table6.tex"  # output
table6_html = "results/tables/table6.html"  # output
table6_summary = "results/tables/table6_summary.md"  # output
figure = "results/figures/objects.png"  # output
scaling_figure = "results/figures/objects_scaling.png"  # output
levels = [0, 1, 2, 3, 4]
runs = 20
threads = 1

# %%
from pathlib import Path

import pandas as pd
from IPython.display import Image, Markdown, display

from sdm.io import write_text
from sdm.report import objects as report

frames = [pd.read_csv(path) for path in runs_files]
shared = pd.read_csv(table2_distances)
table = report.table6(frames, shared[shared["level"].isin(levels)])
report.write_table6(table, Path(table6_csv).with_suffix(""))
display(Markdown(Path(table6_md).read_text()))

# %%
scaling = report.scaling_table([pd.read_csv(path) for path in scaling_files]) if scaling_files else None
summary = report.table6_summary(table, scaling)
write_text(table6_summary, summary)
display(Markdown(summary))

# %%
report.plot_table6(table, figure)
display(Image(figure))
if scaling is not None:
    report.plot_scaling(scaling, scaling_figure)
    display(Image(scaling_figure))

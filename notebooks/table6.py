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
# Gathers `objects_runs` (one file per screen, sharing level and noise level) and `objects_scaling` (one file per K
# cars per image): per screen scale, sharing level, noise level and method, the distance per unit to theta* (mean,
# median, Q3) against doing nothing, the exact-match set's median extent and the CPU time per configuration,
# Table 2's runs quoted as the shared level; the figure of the means; the scaling figure (error against CPU time,
# one curve per K); the summary in plain words (`sdm.experiments.report.objects`; docs/method/objects.md); and every run's
# per-unit records in one compressed file, so that any paired comparison can be checked without rerunning.

# %% tags=["parameters"]
runs_files = []  # input: objects_runs' files
scaling_files = []  # input: objects_scaling's files
table2_distances = "results/noise/distances.csv"  # input: Table 2's runs (the shared level)
table6_csv = "results/tables/table6.csv"  # output
table6_md = "results/tables/table6.md"  # output
table6_tex = "results/tables/table6.tex"  # output
table6_html = "results/tables/table6.html"  # output
table6_summary = "results/tables/table6_summary.md"  # output
table6_units = "results/tables/table6_units.csv.gz"  # output: every per-unit record and scaling record, gzip
table6_verdict = "results/tables/table6_verdict.json"  # output: the verdict's facts of Table 6
figure = "results/figures/objects.png"  # output
scaling_figure = "results/figures/objects_scaling.png"  # output
runs = 20
threads = 1

# %%
from pathlib import Path

from IPython.display import Image, Markdown, display

from sdm.io import write_bytes, write_json, write_text
from sdm.experiments.report import objects as report
from sdm.experiments.report import scaling as scaling_report
from sdm.experiments.report.io import read_csv

frames = [read_csv(path) for path in runs_files]
noise_levels = sorted({int(noise_level) for frame in frames for noise_level in frame["noise_level"]})
shared = read_csv(table2_distances)
table = report.table6(frames, shared[shared["noise_level"].isin(noise_levels)])
report.write_table6(table, Path(table6_csv).with_suffix(""))
display(Markdown(Path(table6_md).read_text()))

# %%
scaling_frames = [read_csv(path) for path in scaling_files]
scaling = scaling_report.scaling_table(scaling_frames) if scaling_frames else None
write_bytes(table6_units, report.units_archive(frames, scaling_frames))
summary = scaling_report.with_scaling(report.table6_summary(table, frames), scaling)
write_text(table6_summary, summary)
write_json(table6_verdict, report.verdict_facts(table))  # what the README's verdict says of Table 6, as data
display(Markdown(summary))

# %%
report.plot_table6(table, figure)
display(Image(figure))
if scaling is not None:
    scaling_report.plot_scaling(scaling, scaling_figure)
    display(Image(scaling_figure))

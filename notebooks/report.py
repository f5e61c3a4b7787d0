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
# # Stage 10: the reproduction report
#
# Every number of Tables 1 and 2 beside the paper's, checked against the acceptance criteria of the
# project's issue 4 (Table 2's noise-free mean at most 1e-3 m; each noisy mean within 0.5x to 2x of the
# paper's; Table 1's pick beside the paper's). The text is built by `sdm.report.reproduction` from the
# measured tables only.

# %% tags=["parameters"]
table1 = "results/tables/table1.csv"
table2 = "results/tables/table2.csv"
distances = "results/noise/distances.csv"
stats = "results/sky/stats.json"
summary = "results/data/summary.json"
report = "results/report/reproduction.md"  # output
config = {}
threads = 1

# %%
import pandas as pd
from IPython.display import Markdown, display

from sdm.report.io import read_json, write_text
from sdm.report.reproduction import build_report

text = build_report(
    pd.read_csv(table1),
    pd.read_csv(table2),
    pd.read_csv(distances),
    read_json(stats),
    read_json(summary),
    config,
)
write_text(report, text)
display(Markdown(text))

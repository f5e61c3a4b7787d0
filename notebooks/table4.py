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
# # Beyond the paper, Table 4: Table 2 per gradient rule
#
# The runs of the stage `rule_runs` (one file per rule and noise level) beside the paper's rule's own runs
# with the same (level, run), i.e. Table 2's runs (`table2_distances`): both sides of each row saw the same
# noisy targets. The bar "half the paper's mean": at most half the paper's published mean at every noisy
# level, the paper's mean noise-free. Every expected (rule, level, run) must be there.

# %% tags=["parameters"]
rule_files = []  # input: the rule_runs files
table4_bias = "results/tables/table4_bias.csv"  # input: where each rule's flow vanishes, per level (rule_bias)
table2_distances = "results/noise/distances.csv"  # input: Table 2's runs (the paper's rule)
baseline_run_files = []  # optional input: Table 3's per-run files (the rules beside the baselines, CMA-ES's rows)
sdm_timings = []  # input: Table 2's noise jobs' timing records (the paper's rule's time per run)
floor_files = []  # optional input: the floor_runs files (the floor's rows)
names = ["closed"]  # the rules expected
noise_levels = [0, 1, 2, 3, 4]  # the levels expected
runs = 2  # the runs 0..runs-1 each (rule, level) must hold
table4_csv = "results/tables/table4.csv"  # output
table4_md = "results/tables/table4.md"  # output: written beside table4_csv, same stem
table4_tex = "results/tables/table4.tex"  # output: written beside table4_csv, same stem
table4_html = "results/tables/table4.html"  # output: written beside table4_csv, same stem (for the Snakemake report)
table4_summary = "results/tables/table4_summary.md"  # output: plain words, for the report
figure = "results/figures/research_rules.png"  # output
threads = 1

# %%
from pathlib import Path

import pandas as pd
from IPython.display import Markdown, display

from sdm.experiments import single_thread
from sdm.experiments.report.figures import show_figure
from sdm.experiments.report.io import read_csv, read_json, write_text
from sdm.experiments.report.research import (
    CMAES_ROW, TABLE4_FORMAT, bias_summary, gathered_runs, reference_rows, rule_times, rules_against_baselines,
    rules_figure, table4_display,
    table4_frame, table4_summary as summary_of_table4, write_table4,
)
from sdm.experiments.report.tables import to_markdown

single_thread(threads)
expected = {(name, noise_level, run) for name in names for noise_level in noise_levels for run in range(runs)}
rule_runs = gathered_runs(rule_files, ("rule", "noise_level", "run"), expected, "Table 4")
# Beside the rules: CMA-ES (Table 3's runs) and the floor (each run's exact-mismatch minimiser), on their own
# paired runs; every row is compared with CMA-ES on the runs both have (the bar "within 2x of CMA-ES":
# at most 2x its mean).
baseline_runs = pd.concat([read_csv(path) for path in baseline_run_files]) if baseline_run_files else None
floor_runs = pd.concat([read_csv(path) for path in floor_files]) if floor_files else None
references = reference_rows(baseline_runs, floor_runs)
cmaes_runs = references[references["rule"] == CMAES_ROW]
table4 = table4_frame(pd.concat([rule_runs[references.columns], references], ignore_index=True),
                      read_csv(table2_distances), cmaes_runs if len(cmaes_runs) else None)
written = write_table4(table4, Path(table4_csv).with_suffix(""))
assert {str(path) for path in written} == {table4_csv, table4_md, table4_tex, table4_html}, written
display(Markdown(to_markdown(table4_display(table4), TABLE4_FORMAT)))
show_figure(rules_figure(table4), figure)

# %% [markdown]
# ## In plain words (every number from the table above)

# %%
answer = summary_of_table4(table4) + rule_times(rule_runs, [read_json(path) for path in sdm_timings])
if baseline_runs is not None:  # Table 3 ran: the rules beside its baselines, on the same (level, run)
    answer += rules_against_baselines(rule_runs, baseline_runs)

# %% [markdown]
# ## Why each rule lands where it does (measured by the stage `rule_bias`, `sdm.experiments.rule_bias`)

# %%
answer += "\n" + bias_summary(read_csv(table4_bias), table4)
write_text(table4_summary, answer)
display(Markdown(answer))

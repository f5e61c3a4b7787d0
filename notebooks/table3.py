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
# # Table 3: SDM against the losses a researcher would use instead
#
# The paper says SDM "translates an existing point to its corresponding screen position instead of
# bubbling a point at a certain screen position", unlike image-loss optimisation, and compares with
# nothing. Here every method estimates theta = (a, b) from the same training configurations:
#
# | method | loss | optimiser |
# |---|---|---|
# | `sdm` | SDM's dynamic gradient flow (Table 2's tuned settings) | SGD, zoom levels s..0 |
# | `silhouette` | soft IoU of Gaussian-splat soft silhouettes (SoftRas style) vs the target | Adam, sigma 2^k px, k = s..0 |
# | `chamfer` | 2D Chamfer distance, projected points vs target pixel centres | Adam |
# | `sinkhorn` | Sinkhorn divergence (geomloss) between the same point sets | Adam, blur 2^k px |
# | `cmaes` | exact count of mismatched pixels at zoom 0 (FP + FN) | CMA-ES (pycma), fixed budget |
#
# Each baseline was tuned on its own small grid by Table 1's criterion (the stage `baseline_tune`), then
# run per noise level on the *same* noisy targets as Table 2's runs (the stage `baseline_runs`), so the
# comparison is paired.
#
# **SDM is not trained again here.** Its rows are Table 2's runs themselves (`table2_distances`, the noise
# stage's per-run results): run r at level n is the same seed, hence the same noisy targets and shuffling,
# as each baseline's run (n, r). Its time per run is what the noise stage measured while producing them
# (`sdm_timings`: per chunk, the wall seconds of `sdm.experiments.noise_runs` over the chunk's runs, trained
# together as one program on one thread; neither the notebook's start nor reading the data counted),
# summed per level and divided by the level's runs (drawing the noisy targets included). The baselines'
# seconds are the `seconds` column of `sdm.experiments.baselines.baseline_noise_runs`: their fits' wall time per run, on one
# thread as well.

# %% tags=["parameters"]
tuning_files = []  # input: the baseline_tune files, one per method, in the order of `methods`
run_files = []  # input: the baseline_runs files
table2_distances = "results/noise/distances.csv"  # input: Table 2's per-run results, SDM's rows
sdm_timings = []  # input: the noise jobs' timing files (SDM's seconds per run; none: no seconds)
floor_files = []  # optional input: the floor_runs files (the floor's rows; none: no floor)
floor_settings = {}  # the floor's search settings (floor.settings), stated in the summary
methods = ["silhouette", "chamfer", "sinkhorn", "cmaes"]  # the baselines (SDM's rows are Table 2's)
noise_levels = [0, 1, 2, 3, 4]
runs = 2  # the runs 0..runs-1 of each level
shift = [0.517, 0.303]
table3_csv = "results/tables/table3.csv"  # output
table3_md = "results/tables/table3.md"  # output: written beside table3_csv, same stem
table3_tex = "results/tables/table3.tex"  # output: written beside table3_csv, same stem
table3_html = "results/tables/table3.html"  # output: written beside table3_csv, same stem (for the Snakemake report)
tuning_csv = "results/tables/table3_tuning.csv"  # output
tuning_md = "results/tables/table3_tuning.md"  # output: written beside tuning_csv, same stem
figure = "results/figures/baselines.png"  # output
summary = "results/tables/table3_summary.md"  # output: the answer in plain words, for the report
threads = 1

# %%
from pathlib import Path

import pandas as pd
from IPython.display import Markdown, display

from sdm.errors import SDMInputError
from sdm.experiments import single_thread
from sdm.experiments.report.baselines import (
    FLOOR, RUN_COLUMNS, TABLE3_FORMAT, TUNING_FORMAT, baselines_figure, floor_frame, floor_summary, table2_runs, table3_display,
    table3_frame, table3_summary, tuning_frame, write_table3,
)
from sdm.experiments.report.figures import show_figure
from sdm.experiments.report.io import read_csv, read_json, write_csv, write_text
from sdm.experiments.report.tables import to_markdown

single_thread(threads)
if len(tuning_files) != len(methods):
    raise SDMInputError(f"parameter 'tuning_files': need one per method ({len(methods)}), got {len(tuning_files)}")

# %% [markdown]
# ## Table 3 and the figure

# %%
baseline_runs = pd.concat([read_csv(path) for path in run_files], ignore_index=True)
# Table 3 pairs every method on runs 0..runs-1 (baselines.runs); a method given more (baselines.runs_by_method:
# CMA-ES's 60, for Table 4) is read here on those runs only, so that each row holds the same runs.
baseline_runs = baseline_runs[baseline_runs["run"] < runs].reset_index(drop=True)
# SDM's rows: Table 2's runs with the same (level, run), i.e. the same noisy targets, and the noise
# stage's own time per run (see the top of this notebook).
sdm_runs = table2_runs(read_csv(table2_distances), [read_json(path) for path in sdm_timings], noise_levels,
                       list(range(runs)))
unpaired = set(zip(baseline_runs["noise_level"], baseline_runs["run"])) - set(zip(sdm_runs["noise_level"], sdm_runs["run"]))
if unpaired:
    raise SDMInputError(f"baseline runs without an SDM run to pair with: {sorted(unpaired)[:5]} (parameters "
                        f"'levels' and 'runs' must cover every run file)")
print(f"SDM rows from Table 2: {len(sdm_runs)} runs; seconds per run by level: "
      + ", ".join(f"{noise_level}: {value:.3f}" for noise_level, value in sdm_runs.groupby("noise_level")["seconds"].first().items()))
# The floor's rows: each run's exact-mismatch minimiser (the stage floor_runs), read against, not ranked.
floor_runs = pd.concat([read_csv(path) for path in floor_files], ignore_index=True) if floor_files else None
floor_rows = [floor_runs.assign(method=FLOOR)[list(RUN_COLUMNS)]] if floor_files else []
all_runs = pd.concat([sdm_runs, baseline_runs, *floor_rows], ignore_index=True)
table3 = table3_frame(all_runs, shift=shift)
written = write_table3(table3, Path(table3_csv).with_suffix(""))
assert {str(path) for path in written} == {table3_csv, table3_md, table3_tex, table3_html}, written
display(Markdown(to_markdown(table3_display(table3), TABLE3_FORMAT)))

tuning_table = tuning_frame([read_csv(path) for path in tuning_files])
write_csv(tuning_csv, tuning_table)
write_text(tuning_md, to_markdown(tuning_table, TUNING_FORMAT))
display(Markdown(to_markdown(tuning_table, TUNING_FORMAT)))
show_figure(baselines_figure(table3, all_runs, shift), figure)

# %% [markdown]
# ## The answer, in plain words (every number from Table 3)

# %%
answer = table3_summary(table3, table2_runs=int(read_csv(table2_distances).groupby("noise_level").size().min()))
if floor_files:
    answer += floor_summary(floor_frame(floor_runs), floor_settings)
write_text(summary, answer)
display(Markdown(answer))

# %% [markdown]
# Time per run (seconds, this machine, one thread) per method, over all levels (SDM's: the noise stage's timing):

# %%
display(table3.groupby("method", sort=False)["seconds_per_run"].mean().to_frame())

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
# # Beyond the paper, Table 5: the shift with depth
#
# The runs of the stage `depth_runs` (one file per c* and noise level): per c* and level, the mean absolute
# errors of a, b and c, the signed mean of c - c*, and the distances to (a*, b*) and (a*, b*, c*). The depth bar,
# noise-free: a, b within 2e-3 m, c within 2e-2 m. Every expected (c*, level, run) must be there. Then why c is
# biased under noise, measured at theta* (`sdm.experiments.depth_bias`).

# %% tags=["parameters"]
depth_files = []  # input: the depth_runs files
sky = "results/sky/sky.bin"  # input
split = "results/split/split.json"  # input
schedule = "closed_centred_r1"  # the depth runs' rule or schedule
s = 4  # coarsest zoom level (train.s)
seed = 0  # noise seed (noise.seed): the measurement takes run 0's draw of each level
shift = [0.517, 0.303]  # (a*, b*), metres
table5_bias = "results/tables/table5_bias.csv"  # output: the depth flow at theta*, per c*, level and zoom
shifts_c = [1.0]  # the c* expected
noise_levels = [0, 1, 2, 3, 4]  # the levels expected
runs = 2  # the runs 0..runs-1 each (c*, level) must hold
table5_csv = "results/tables/table5.csv"  # output
table5_md = "results/tables/table5.md"  # output: written beside table5_csv, same stem
table5_tex = "results/tables/table5.tex"  # output: written beside table5_csv, same stem
table5_html = "results/tables/table5.html"  # output: written beside table5_csv, same stem (for the Snakemake report)
table5_summary = "results/tables/table5_summary.md"  # output: plain words, for the report
figure = "results/figures/research_depth.png"  # output
threads = 1

# %%
from pathlib import Path

from IPython.display import Markdown, display

import pandas as pd

from sdm.experiments import depth_bias, load_split, single_thread
from sdm.experiments.report.figures import show_figure
from sdm.experiments.report.io import read_json, write_csv, write_text
from sdm.experiments.report.depth import (
    TABLE5_FORMAT, depth_figure, table5_bias_summary, table5_display, table5_frame,
    table5_summary as summary_of_table5, write_table5,
)
from sdm.experiments.report.research import gathered_runs
from sdm.experiments.report.tables import to_markdown
from sdm.train import TrainSettings, parse_schedule

single_thread(threads)
expected = {(float(value), noise_level, run) for value in shifts_c for noise_level in noise_levels for run in range(runs)}
depth_runs = gathered_runs(depth_files, ("c_true", "noise_level", "run"), expected, "Table 5")
table5 = table5_frame(depth_runs)
written = write_table5(table5, Path(table5_csv).with_suffix(""))
assert {str(path) for path in written} == {table5_csv, table5_md, table5_tex, table5_html}, written
display(Markdown(to_markdown(table5_display(table5), TABLE5_FORMAT)))
show_figure(depth_figure(table5), figure)

# %% [markdown]
# ## In plain words (every number from the table above)

# %%
display(Markdown(summary_of_table5(table5)))

# %% [markdown]
# ## Why c is biased under noise (measured at theta*)
#
# `sdm.experiments.depth_bias` puts the points at theta* = (a*, b*, c*) on run 0's noisy targets of each level and
# measures the depth flow there: at the finest level where the schedule moves c with its rule
# (`TrainSettings.depth_zoom`), and at zoom 0 with the refinement's rule when the schedule refines (its passes
# move c). `offset_c` is where the mean flow on c vanishes (flow over its stiffness): where SGD on c settles.
# `edge_share` is the part of the pull that comes from the points at the edges of the discs, and
# `unmatched_edge` / `unmatched_inside` how often those / the other points land on a block the noise emptied.

# %%
train_set, _, _ = load_split(sky, read_json(split))
rule, refine = parse_schedule(schedule)
measured = [(rule, min(TrainSettings.depth_zoom, s))] + ([(refine.rule, 0)] if refine and refine.moves_c else [])
bias = pd.concat([depth_bias(train_set, value, noise_levels, seed, schedule=name, s=s, zooms=[zoom], shift=shift)
                  .assign(rule=name) for value in shifts_c for name, zoom in measured], ignore_index=True)
write_csv(table5_bias, bias)
display(bias)
answer = table5_bias_summary(table5, bias)
write_text(table5_summary, summary_of_table5(table5) + "\n" + answer)
display(Markdown(answer))

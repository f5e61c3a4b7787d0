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
# # Beyond the paper: Table 2 per gradient rule (Table 4) and the shift with depth (Table 5)
#
# The paper ends with "the solution is stable against noise and has many potentials for further
# improvements", and poses the general shift (a, b, c) with depth while solving (a, b) only. Two
# experiments take that further (docs/method.md, "Beyond the paper"):
#
# - **Table 4.** Table 2 again with another gradient rule (`sdm.FLOW_RULES`; `closed` fills the holes the
#   noise leaves in the target before matching). Run r at level n trains on exactly the noisy targets and
#   shuffling of Table 2's run r (the seed from (seed, n, r) does not depend on the rule), so each rule sits
#   beside the paper's rule on the same draws. The bar: at most half the paper's published mean
#   at every noisy level, the paper's mean noise-free.
# - **Table 5.** The training set's targets rebuilt for its points moved by theta* = (a*, b*, c*), noise
#   as Table 2's (the same seeds), and (a, b, c) trained from (0, 0, 0) with the depth flow
#   (`TrainSettings(fit_depth=True)`). The bar, noise-free: a, b within 2e-3 m, c within 2e-2 m.
#
# One notebook, four parts, chosen by `part`: `rules` (one rule's runs at one level), `depth` (one c*'s runs
# at one level), `table4` and `table5` (gather the run files, write the table, its figure and the plain words).

# %% tags=["parameters"]
part = "rules"  # rules | depth | table4 | table5
sky = "results/sky/sky.bin"  # input of rules and depth
split = "results/split/split.json"  # input of rules and depth
best = "results/tuning/best.json"  # input of rules and depth: the tuned settings (Table 1)
runs_file = "results/research/rules/closed_level0.csv"  # output of rules and depth: one row per run
flow = "closed"  # the gradient rule of the runs (rules and depth)
c = 1.0  # depth: the true depth shift c*, metres
depth_lr_scale = 20.0  # depth: learning rate of c relative to the tuned lr
level = 0  # rules and depth: the noise level
run_indices = [0, 1]  # rules and depth: the runs; table4 and table5: the runs each file must hold
s = 4
batch_size = 16
lr_decay = 0.5
seed = 0  # noise seed (noise.seed): run r at level n draws its noise and shuffling from (seed, n, r)
shift = [0.517, 0.303]  # (a*, b*), metres
rule_files = []  # input of table4
table2_distances = "results/noise/distances.csv"  # input of table4: Table 2's runs (the paper's rule)
baseline_run_files = []  # optional input of table4: Table 3's per-run files (the rules beside the baselines)
names = ["closed"]  # table4: the rules expected
depth_files = []  # input of table5
shifts_c = [1.0]  # table5: the c* expected
levels = [0, 1, 2, 3, 4]  # table4 and table5: the levels expected
table4_csv = "results/tables/table4.csv"  # output of table4
table4_md = "results/tables/table4.md"  # output of table4: written beside table4_csv, same stem
table4_tex = "results/tables/table4.tex"  # output of table4: written beside table4_csv, same stem
table4_summary = "results/tables/table4_summary.md"  # output of table4: plain words, for the report
table5_csv = "results/tables/table5.csv"  # output of table5
table5_md = "results/tables/table5.md"  # output of table5: written beside table5_csv, same stem
table5_tex = "results/tables/table5.tex"  # output of table5: written beside table5_csv, same stem
table5_summary = "results/tables/table5_summary.md"  # output of table5: plain words, for the report
figure = "results/figures/research_rules.png"  # output of table4 and table5
threads = 1

# %%
from dataclasses import replace
from pathlib import Path

import pandas as pd
from IPython.display import Markdown, display

from sdm.errors import SDMInputError
from sdm.experiments import depth_noise_runs, load_split, rule_noise_runs, settings_for, single_thread
from sdm.report.figures import show_figure
from sdm.report.io import read_json, write_csv, write_text
from sdm.report.research import (
    TABLE4_FORMAT, TABLE5_FORMAT, depth_figure, rules_against_baselines, rules_figure, table4_display, table4_frame,
    table4_summary as summary_of_table4, table5_display, table5_frame, table5_summary as summary_of_table5,
    write_research_table,
)
from sdm.report.tables import to_markdown

single_thread(threads)
if part not in ("rules", "depth", "table4", "table5"):
    raise SDMInputError(f"parameter 'part': must be rules, depth, table4 or table5, got {part!r}")
if part in ("rules", "depth"):
    tuned = read_json(best)
    train_set, _, camera = load_split(sky, read_json(split))
    settings = settings_for(tuned["n_epoch"], tuned["lr"], s, batch_size, lr_decay, seed)
    print(f"{len(train_set)} training configurations; n_epoch {settings.n_epoch}, lr {settings.lr:g}, rule {flow}")

# %% [markdown]
# ## The runs
#
# `rules`: `sdm.experiments.rule_noise_runs`, i.e. Table 2's `noise_runs` with the rule's flow (runs trained
# together, each moved only by its own flow). `depth`: `sdm.experiments.depth_noise_runs`, trained together
# the same way with `fit_depth` (each run equal to the run trained alone to 1e-12 m: the depth flow is a
# float sum); each row has the fitted (a, b, c), the absolute errors and the distances to (a*, b*) and to
# (a*, b*, c*), in metres.

# %%
if part == "rules":
    runs = rule_noise_runs(train_set, flow, level, run_indices, settings, shift=shift, camera=camera)
elif part == "depth":
    depth_settings = replace(settings, flow=flow, depth_lr_scale=depth_lr_scale)
    try:
        runs = depth_noise_runs(train_set, c, level, run_indices, depth_settings, shift=shift, camera=camera)
    except SDMInputError as error:
        if str(error).startswith("c = "):  # the config's c* itself is impossible for these points
            raise SDMInputError(f"config key 'research.depth.shifts_c': {error}") from None
        raise
if part in ("rules", "depth"):
    write_csv(runs_file, runs)
    shown = runs.drop(columns=["seed"])
    print(f"level {level}, runs {run_indices[0]}..{run_indices[-1]}: mean distance "
          f"{1000 * runs['distance'].mean():.3f}e-3 m")
    display(shown.describe())

# %% [markdown]
# ## Table 4: Table 2 per rule
#
# Every expected (rule, level, run) must be there; the paper's rule's numbers are Table 2's runs with the
# same (level, run), so both sides of each row saw the same noisy targets.

# %%
def gathered(paths, keys, expected, what):
    """The run files concatenated, checked to hold exactly the expected runs."""
    frame = pd.concat([pd.read_csv(path) for path in paths], ignore_index=True)
    found = set(zip(*(frame[key] for key in keys)))
    if found != expected:
        raise SDMInputError(f"{what}: missing runs {sorted(expected - found)[:5]}, unexpected {sorted(found - expected)[:5]}")
    return frame


if part == "table4":
    rule_runs = gathered(rule_files, ("flow", "level", "run"),
                         {(name, lvl, run) for name in names for lvl in levels for run in run_indices}, "Table 4")
    table4 = table4_frame(rule_runs, pd.read_csv(table2_distances))
    written = write_research_table(table4, Path(table4_csv).with_suffix(""), 4)
    assert {str(path) for path in written} == {table4_csv, table4_md, table4_tex}, written
    display(Markdown(to_markdown(table4_display(table4), TABLE4_FORMAT)))
    show_figure(rules_figure(table4), figure)

# %% [markdown]
# ## Table 5: the shift with depth

# %%
if part == "table5":
    depth_runs = gathered(depth_files, ("c_true", "level", "run"),
                          {(float(value), lvl, run) for value in shifts_c for lvl in levels for run in run_indices},
                          "Table 5")
    table5 = table5_frame(depth_runs)
    written = write_research_table(table5, Path(table5_csv).with_suffix(""), 5)
    assert {str(path) for path in written} == {table5_csv, table5_md, table5_tex}, written
    display(Markdown(to_markdown(table5_display(table5), TABLE5_FORMAT)))
    show_figure(depth_figure(table5), figure)

# %% [markdown]
# ## In plain words (every number from the table above)

# %%
if part == "table4":
    answer = summary_of_table4(table4)
    if baseline_run_files:  # Table 3 ran: the rules beside its baselines, on the same (level, run)
        answer += rules_against_baselines(rule_runs, pd.concat([pd.read_csv(path) for path in baseline_run_files]))
    write_text(table4_summary, answer)
    display(Markdown(answer))
elif part == "table5":
    answer = summary_of_table5(table5)
    write_text(table5_summary, answer)
    display(Markdown(answer))

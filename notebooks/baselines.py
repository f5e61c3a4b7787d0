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
# # Stage 9: Table 3, SDM against the losses a researcher would use instead
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
# Each baseline is tuned on its own small grid by Table 1's criterion (dev loss: mean false-positive
# pixels per dev configuration, noise-free); SDM keeps Table 1's pick. Then, per noise level and run,
# every method sees the *same* noisy targets (the run seed of Table 2), so the comparison is paired.
#
# One notebook, three parts, chosen by `part`, so the workflow can fan the work out:
# `tune` (the grids of `methods`), `runs` (`methods` x `levels` x `run_indices`), `table` (Table 3,
# the tuning table and the figure from the run files); `fit` is `tune` then `runs` (one job per method
# saves a notebook start per level), `all` does the three in a row.

# %% tags=["parameters"]
sky = "results/sky/sky.bin"  # input
split = "results/split/split.json"  # input
best = "results/tuning/best.json"  # input: SDM's tuned settings (Table 1)
part = "all"  # tune | runs | fit (tune then runs) | table | all
methods = ["sdm", "silhouette", "chamfer", "sinkhorn", "cmaes"]
settings = {}  # per method (config baselines.<method>): setting -> value, or a list of values to tune over
tuning_files = []  # one CSV per method (ignored for sdm): output of `tune`, input of `runs` and `table`
runs_file = "results/baselines/runs.csv"  # output of `runs`: one row per (method, level, run)
run_files = []  # input of `table` (default: [runs_file])
table2_distances = ""  # optional input: Table 2's per-run distances: checks SDM's runs (`runs`), or stands in
# for them when `sdm` is not among the run files (`table`: SDM's rows are then Table 2's, without seconds)
levels = [0, 1, 2, 3, 4]
run_indices = [0, 1]
table3_csv = "results/tables/table3.csv"  # output of `table`
table3_md = "results/tables/table3.md"  # output of `table`: written beside table3_csv, same stem
table3_tex = "results/tables/table3.tex"  # output of `table`: written beside table3_csv, same stem
tuning_csv = "results/tables/table3_tuning.csv"  # output of `table`
tuning_md = "results/tables/table3_tuning.md"  # output of `table`: written beside tuning_csv, same stem
figure = "results/figures/baselines.png"  # output of `table`
summary = "results/tables/table3_summary.md"  # output of `table`: the answer in plain words, for the report
s = 4
batch_size = 16
lr_decay = 0.5
train_seed = 0  # seed of the tuning fits (as train.seed for Table 1)
seed = 0  # noise seed (as noise.seed for Table 2): run seeds come from (seed, level, run)
shift = [0.517, 0.303]
threads = 1

# %%
from pathlib import Path

import pandas as pd
from IPython.display import Markdown, display

from sdm.baselines import best_settings, method, noise_runs, settings_grid, tune
from sdm.errors import SDMInputError
from sdm.experiments import load_split, settings_for, single_thread
from sdm.report.io import read_json, write_csv, write_text

single_thread(threads)
if part not in ("tune", "runs", "fit", "table", "all"):
    raise SDMInputError(f"parameter 'part': must be tune, runs, fit, table or all, got {part!r}")
for name in methods:
    method(name, "baselines.methods")
for name in settings:
    method(name, f"baselines.{name}")
if len(tuning_files) != len(methods):
    raise SDMInputError(f"parameter 'tuning_files': need one per method ({len(methods)}), got {len(tuning_files)}")
tuning_of = dict(zip(methods, tuning_files))
needs_data = part in ("tune", "runs", "fit", "all")
if needs_data:
    train_set, dev_set, camera = load_split(sky, read_json(split))
    print(f"{len(train_set)} training and {len(dev_set)} dev configurations")

# %% [markdown]
# ## Tuning (like Table 1)
#
# Each baseline's grid runs on the noise-free training set with seed `train_seed`; the cell with the
# lowest dev loss is chosen. The distance to theta* is reported but plays no part in the choice.

# %%
if part in ("tune", "fit", "all"):
    for name in methods:
        if name == "sdm":
            continue  # SDM's cell is Table 1's (best.json)
        cells = settings_grid(name, settings.get(name, {}))
        tuning = tune(name, train_set, dev_set, cells, seed=train_seed, s=s, shift=shift, camera=camera)
        write_csv(tuning_of[name], tuning)
        chosen = tuning[tuning["best"]].iloc[0]
        print(f"{name}: {len(cells)} cells, {tuning['seconds'].sum():.1f} s; chosen cell {int(chosen['cell'])}, "
              f"dev loss {chosen['dev_loss']:.3f}, distance {1000 * chosen['distance']:.3f}e-3 m")
        display(tuning.drop(columns=["method"]))

# %% [markdown]
# ## Paired noise runs
#
# Run `r` at level `n` draws its noisy targets from `run_seed(seed, n, r)`, exactly as Table 2's run;
# the same seed drives the method's own randomness (mini-batches, subsampling, CMA-ES).

# %%
def settings_of(name):
    if name == "sdm":
        tuned = read_json(best)
        return settings_for(tuned["n_epoch"], tuned["lr"], s, batch_size, lr_decay, train_seed)
    return best_settings(name, pd.read_csv(tuning_of[name]))


if part in ("runs", "fit", "all"):
    frames = []
    for name in methods:
        chosen = settings_of(name)
        print(f"{name}: {chosen}")
        for level in levels:
            frame = noise_runs(name, train_set, level, run_indices, chosen, seed, shift=shift, camera=camera)
            frames.append(frame)
            print(f"  level {level}: mean distance {1000 * frame['distance'].mean():.3f}e-3 m, "
                  f"{frame['seconds'].mean():.2f} s per run")
    runs = pd.concat(frames, ignore_index=True)
    write_csv(runs_file, runs)

# %% [markdown]
# SDM's runs here must be Table 2's runs (same seed, same noise, same shuffling): checked when
# Table 2's distances are given.

# %%
if part in ("runs", "fit", "all") and "sdm" in methods and table2_distances:
    table2 = pd.read_csv(table2_distances).set_index(["level", "run"])
    ours = runs[runs["method"] == "sdm"].set_index(["level", "run"])
    common = ours.index.intersection(table2.index)
    gap = (ours.loc[common, ["a", "b"]] - table2.loc[common, ["a", "b"]]).abs().to_numpy().max() if len(common) else 0.0
    print(f"SDM runs matched with Table 2: {len(common)} of {len(ours)}, largest theta difference {gap:.3g} m")
    assert gap < 1e-9, "SDM's runs differ from Table 2's runs with the same seeds"

# %% [markdown]
# ## Table 3 and the figure

# %%
if part in ("table", "all"):
    from sdm.report.baselines import (
        TABLE3_FORMAT, TUNING_FORMAT, baselines_figure, table3_display, table3_frame, table3_summary, tuning_frame,
        write_table3,
    )
    from sdm.report.figures import show_figure
    from sdm.report.tables import to_markdown

    all_runs = pd.concat([pd.read_csv(path) for path in (run_files or [runs_file])], ignore_index=True)
    if "sdm" not in set(all_runs["method"]) and table2_distances:
        # SDM not re-run here: its rows are Table 2's runs with the same (level, run), i.e. the same noisy
        # targets; Table 2 records no time per run, so SDM's seconds stay empty.
        table2 = pd.read_csv(table2_distances)
        pairs = set(zip(all_runs["level"], all_runs["run"]))
        table2 = table2[[pair in pairs for pair in zip(table2["level"], table2["run"])]]
        all_runs = pd.concat([table2.assign(method="sdm", seconds=float("nan")), all_runs], ignore_index=True)
        print(f"SDM rows from Table 2: {len(table2)} runs")
    table3 = table3_frame(all_runs, shift=shift)
    written = write_table3(table3, Path(table3_csv).with_suffix(""))
    assert {str(path) for path in written} == {table3_csv, table3_md, table3_tex}, written
    display(Markdown(to_markdown(table3_display(table3), TABLE3_FORMAT)))

    tunings = [pd.read_csv(tuning_of[name]) for name in methods if name != "sdm" and Path(tuning_of[name]).is_file()]
    if tunings:
        tuning_table = tuning_frame(tunings)
        write_csv(tuning_csv, tuning_table)
        write_text(tuning_md, to_markdown(tuning_table, TUNING_FORMAT))
        display(Markdown(to_markdown(tuning_table, TUNING_FORMAT)))
    show_figure(baselines_figure(table3, all_runs, shift), figure)

# %% [markdown]
# ## The answer, in plain words (every number from Table 3)

# %%
if part in ("table", "all"):
    answer = table3_summary(table3) if "sdm" in set(table3["method"]) else "SDM was not run: nothing to compare with.\n"
    write_text(summary, answer)
    display(Markdown(answer))

# %% [markdown]
# Time per run (seconds, this machine, one thread) per method, over all levels:

# %%
if part in ("table", "all"):
    display(table3.groupby("method", sort=False)["seconds_per_run"].mean().to_frame())

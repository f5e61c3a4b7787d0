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
# **SDM is not trained again here.** Its rows are Table 2's runs themselves (`table2_distances`, the noise
# stage's per-run results): run r at level n is the same seed, hence the same noisy targets and shuffling,
# as each baseline's run (n, r). Its time per run is what the noise stage measured while producing them
# (`sdm_timings`: per chunk, the wall seconds of `sdm.experiments.noise_runs` over the chunk's runs, trained
# together as one program on one thread; neither the notebook's start nor reading the data counted),
# summed per level and divided by the level's runs (drawing the noisy targets included). The baselines'
# seconds are the `seconds` column of `sdm.baselines.noise_runs`: their fits' wall time per run, on one
# thread as well.
#
# One notebook, three parts, chosen by `part`, so the workflow can fan the work out: `tune` (the grids of
# `methods`, one job per method), `runs` (`methods` x `levels` x `run_indices`, one job per method and
# level), `table` (Table 3, the tuning table and the figure from the run files); `all` does the three in
# a row.

# %% tags=["parameters"]
sky = "results/sky/sky.bin"  # input of tune and runs
split = "results/split/split.json"  # input of tune and runs
part = "all"  # tune | runs | table | all
methods = ["silhouette", "chamfer", "sinkhorn", "cmaes"]  # the baselines (SDM's rows are Table 2's)
settings = {}  # per method (config baselines.<method>): setting -> value, or a list of values to tune over
tuning_files = []  # one CSV per method: output of `tune`, input of `runs` and `table` (default: beside runs_file)
runs_file = "results/baselines/runs.csv"  # output of `runs`: one row per (method, level, run)
run_files = []  # input of `table` (default: [runs_file])
table2_distances = "results/noise/distances.csv"  # input of `table`: Table 2's per-run results, SDM's rows
sdm_timings = []  # input of `table`: the noise jobs' timing files (SDM's seconds per run; none: no seconds)
levels = [0, 1, 2, 3, 4]
run_indices = [0, 1]
table3_csv = "results/tables/table3.csv"  # output of `table`
table3_md = "results/tables/table3.md"  # output of `table`: written beside table3_csv, same stem
table3_tex = "results/tables/table3.tex"  # output of `table`: written beside table3_csv, same stem
tuning_csv = "results/tables/table3_tuning.csv"  # output of `table`
tuning_md = "results/tables/table3_tuning.md"  # output of `table`: written beside tuning_csv, same stem
figure = "results/figures/baselines.png"  # output of `table`
summary = "results/tables/table3_summary.md"  # output of `table`: the answer in plain words, for the report
s = 4  # SDM's zoom chain for the dev loss (Table 1's criterion)
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
from sdm.experiments import load_split, single_thread
from sdm.report.io import read_json, write_csv, write_text

single_thread(threads)
if part not in ("tune", "runs", "table", "all"):
    raise SDMInputError(f"parameter 'part': must be tune, runs, table or all, got {part!r}")
for name in methods:
    method(name, "baselines.methods")
    if name == "sdm":
        raise SDMInputError("config key 'baselines.methods': 'sdm' is not a baseline (its rows are Table 2's runs)")
for name in settings:
    method(name, f"baselines.{name}")
tuning_files = tuning_files or [str(Path(runs_file).with_name(f"tuning_{name}.csv")) for name in methods]
if len(tuning_files) != len(methods):
    raise SDMInputError(f"parameter 'tuning_files': need one per method ({len(methods)}), got {len(tuning_files)}")
tuning_of = dict(zip(methods, tuning_files))
if part in ("tune", "runs", "all"):
    train_set, dev_set, camera = load_split(sky, read_json(split))
    print(f"{len(train_set)} training and {len(dev_set)} dev configurations")

# %% [markdown]
# ## Tuning (like Table 1)
#
# Each baseline's grid runs on the noise-free training set with seed `train_seed`; the cell with the
# lowest dev loss is chosen. The distance to theta* is reported but plays no part in the choice.

# %%
if part in ("tune", "all"):
    for name in methods:
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
# the same seed drives the method's own randomness (mini-batches, subsampling, CMA-ES). Each method runs
# with the cell its tuning chose.

# %%
if part in ("runs", "all"):
    frames = []
    for name in methods:
        chosen = best_settings(name, pd.read_csv(tuning_of[name]))
        print(f"{name}: {chosen}")
        for level in levels:
            frame = noise_runs(name, train_set, level, run_indices, chosen, seed, shift=shift, camera=camera)
            frames.append(frame)
            print(f"  level {level}: mean distance {1000 * frame['distance'].mean():.3f}e-3 m, "
                  f"{frame['seconds'].mean():.2f} s per run")
    runs = pd.concat(frames, ignore_index=True)
    write_csv(runs_file, runs)

# %% [markdown]
# ## Table 3 and the figure

# %%
if part in ("table", "all"):
    from sdm.report.baselines import (
        TABLE3_FORMAT, TUNING_FORMAT, baselines_figure, table2_runs, table3_display, table3_frame, table3_summary,
        tuning_frame, write_table3,
    )
    from sdm.report.figures import show_figure
    from sdm.report.tables import to_markdown

    baseline_runs = pd.concat([pd.read_csv(path) for path in (run_files or [runs_file])], ignore_index=True)
    # SDM's rows: Table 2's runs with the same (level, run), i.e. the same noisy targets, and the noise
    # stage's own time per run (see the top of this notebook).
    sdm_runs = table2_runs(pd.read_csv(table2_distances), [read_json(path) for path in sdm_timings], levels,
                           run_indices)
    unpaired = set(zip(baseline_runs["level"], baseline_runs["run"])) - set(zip(sdm_runs["level"], sdm_runs["run"]))
    if unpaired:
        raise SDMInputError(f"baseline runs without an SDM run to pair with: {sorted(unpaired)[:5]} (parameters "
                            f"'levels' and 'run_indices' must cover every run file)")
    print(f"SDM rows from Table 2: {len(sdm_runs)} runs; seconds per run by level: "
          + ", ".join(f"{level}: {value:.3f}" for level, value in sdm_runs.groupby("level")["seconds"].first().items()))
    all_runs = pd.concat([sdm_runs, baseline_runs], ignore_index=True)
    table3 = table3_frame(all_runs, shift=shift)
    written = write_table3(table3, Path(table3_csv).with_suffix(""))
    assert {str(path) for path in written} == {table3_csv, table3_md, table3_tex}, written
    display(Markdown(to_markdown(table3_display(table3), TABLE3_FORMAT)))

    tunings = [pd.read_csv(tuning_of[name]) for name in methods if Path(tuning_of[name]).is_file()]
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
    answer = table3_summary(table3, table2_runs=int(pd.read_csv(table2_distances).groupby("level").size().min()))
    write_text(summary, answer)
    display(Markdown(answer))

# %% [markdown]
# Time per run (seconds, this machine, one thread) per method, over all levels (SDM's: the noise stage's timing):

# %%
if part in ("table", "all"):
    display(table3.groupby("method", sort=False)["seconds_per_run"].mean().to_frame())

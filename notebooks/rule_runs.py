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
# # Beyond the paper, Table 4: one gradient rule's runs at every noise level
#
# The paper ends with "the solution is stable against noise and has many potentials for further
# improvements". Table 4 is Table 2 again with another gradient rule (`sdm.FLOW_RULES`; `closed` fills the
# holes the noise leaves in the target before matching; docs/method/rules.md. Run r at
# level n trains on exactly the noisy targets and shuffling of Table 2's run r (the seed from (seed, n, r)
# does not depend on the rule), so each rule sits beside the paper's rule on the same draws; the stage
# `table4` gathers this stage's files.
#
# `sdm.experiments.rule_noise_runs` is Table 2's `noise_runs` with the rule's flow: the runs are trained
# together, each moved only by its own flow. One job runs every level (one file each): a job's start-up
# (the interpreter, torch, this kernel) costs more than a level's runs; each level runs exactly as alone.

# %% tags=["parameters"]
sky = "results/sky/sky.bin"  # input
split = "results/split/split.json"  # input
best = "results/tuning/best.json"  # input: the tuned settings (Table 1)
runs_files = ["results/research/rules/closed_level0.csv"]  # output: one per level of `levels`, one row per run
schedule = "closed"  # the gradient rule or schedule of the runs
noise_levels = [0]  # the noise levels
runs = 2  # the runs 0..runs-1 (Table 2's runs with the same indices)
s = 4
batch_size = 16
lr_decay = 0.5
seed = 0  # noise seed (noise.seed): run r at level n draws its noise and shuffling from (seed, n, r)
shift = [0.517, 0.303]  # (a*, b*), metres
threads = 1

# %%
import time

from IPython.display import display

from sdm.experiments import rule_noise_runs, single_thread, tuned_training
from sdm.experiments.report.io import read_json, write_csv

single_thread(threads)
train_set, camera, settings = tuned_training(sky, read_json(split), read_json(best), s, batch_size, lr_decay, seed)
print(f"{len(train_set)} training configurations; n_epoch {settings.n_epoch}, lr {settings.lr:g}, rule {schedule}")

# %%
run_indices = list(range(runs))
if len(runs_files) != len(noise_levels):
    raise ValueError(f"runs_files: one per level expected, got {len(runs_files)} for levels {noise_levels}")
for noise_level, runs_file in zip(noise_levels, runs_files):
    started = time.perf_counter()
    results = rule_noise_runs(train_set, schedule, noise_level, run_indices, settings, shift=shift, camera=camera)
    # trained together (as Table 2's noise chunks): a run's share is the level's wall time over its runs,
    # measured as notebooks/noise.py measures the paper's rule (Table 4 sets the two side by side)
    results["seconds"] = (time.perf_counter() - started) / len(run_indices)
    write_csv(runs_file, results)
    print(f"level {noise_level}, runs 0..{runs - 1}: mean distance {1000 * results['distance'].mean():.3f}e-3 m")
    display(results.drop(columns=["seed"]).describe())

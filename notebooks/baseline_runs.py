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
# # Table 3, runs: one baseline's paired noise runs at every level
#
# One job for all the levels (one file each): a job's start-up (the interpreter, torch, this kernel) costs
# about as much as a level's runs. The levels run one after another, each exactly as alone (every run's
# randomness comes from its own seed).
#
# Run r at level n draws its noisy targets from `run_seed(seed, n, r)`, exactly as Table 2's run r; the
# same seed drives the method's own randomness (mini-batches, subsampling, CMA-ES), so the comparison with
# SDM in Table 3 is paired. The method runs with the cell its tuning (the stage `baseline_tune`) chose.
# The `seconds` column is its fits' wall time per run, on one thread.

# %% tags=["parameters"]
sky = "results/sky/sky.bin"  # input
split = "results/split/split.json"  # input
tuning_file = "results/baselines/tuning_chamfer.csv"  # input: the method's tuning (its chosen cell)
runs_files = ["results/baselines/runs_chamfer_level0.csv"]  # output: one per level of `levels`, one row per run
method = "chamfer"  # the baseline
noise_levels = [0]  # the noise levels
runs = 2  # the runs 0..runs-1 (paired with Table 2's runs of the same indices)
seed = 0  # noise seed (as noise.seed for Table 2): run seeds come from (seed, level, run)
shift = [0.517, 0.303]
threads = 1

# %%

from sdm.experiments.baselines import baseline_noise_runs, best_settings
from sdm.experiments import load_split, single_thread
from sdm.experiments.report.io import read_csv, read_json, write_csv

single_thread(threads)
train_set, _, camera = load_split(sky, read_json(split))
chosen = best_settings(method, read_csv(tuning_file))
print(f"{len(train_set)} training configurations; {method}: {chosen}")
if len(runs_files) != len(noise_levels):
    raise ValueError(f"runs_files: one per level expected, got {len(runs_files)} for levels {noise_levels}")
for noise_level, runs_file in zip(noise_levels, runs_files):
    results = baseline_noise_runs(method, train_set, noise_level, list(range(runs)), chosen, seed, shift=shift, camera=camera)
    write_csv(runs_file, results)
    print(f"level {noise_level}: mean distance {1000 * results['distance'].mean():.3f}e-3 m, "
          f"{results['seconds'].mean():.2f} s per run")

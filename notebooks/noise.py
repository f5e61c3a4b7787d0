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
# # Stage 7: noise runs (Table 2)
#
# Robustness (paper, section 5.2): every active pixel of each training target moves by (X, Y), independent
# integers uniform on [-n, n], off-screen ones dropped; then theta~ is trained with the tuned settings and
# its distance to theta* measured. The seed flows one way: `seed` goes into the settings, and run r at level n
# trains with the seed derived from (seed, n, r), which fixes both its noise and its shuffling, so any chunk of
# runs can run anywhere and give the same numbers.
#
# The chunk also records the wall seconds of its runs (the training alone: not the notebook's start,
# nor reading the data) in `timing_file`; Table 3 reports them as SDM's time per run. Nothing of
# Table 2 reads it, so the tables stay the same byte for byte whatever the machine's speed.

# %% tags=["parameters"]
sky = "results/sky/sky.bin"  # input
split = "results/split/split.json"  # input
best = "results/tuning/best.json"  # input: the tuned settings
chunk_file = "results/noise/level0_chunk0.csv"  # output: one row per run
timing_file = "results/noise/level0_chunk0_seconds.json"  # output: wall seconds of the chunk's runs
noise_level = 0
first_run = 0  # the chunk's runs: first_run .. first_run + runs - 1
runs = 2
s = 4
batch_size = 16
lr_decay = 0.5
seed = 0
shift = [0.517, 0.303]
threads = 1

# %%
import time

from sdm.experiments import noise_runs, single_thread, tuned_training
from sdm.experiments.report.io import read_json, write_csv, write_json

single_thread(threads)
run_indices = list(range(first_run, first_run + runs))
train_set, camera, settings = tuned_training(sky, read_json(split), read_json(best), s, batch_size, lr_decay, seed)
print(f"level {noise_level}, runs {run_indices[0]}..{run_indices[-1]}, n_epoch {settings.n_epoch}, lr {settings.lr:g}")
started = time.perf_counter()
results = noise_runs(train_set, noise_level, run_indices, settings, shift=shift, camera=camera)
seconds = time.perf_counter() - started
write_csv(chunk_file, results)
# The runs are trained together as one program (sdm.experiments.noise_runs), so a run's share is
# the chunk's wall time over its runs.
write_json(timing_file, {"noise_level": noise_level, "runs": len(run_indices), "seconds": seconds,
                         "seconds_per_run": seconds / len(run_indices), "threads": threads})
print(f"{len(run_indices)} runs in {seconds:.2f} s ({seconds / len(run_indices):.3f} s per run, {threads} thread(s))")

# %%
results.assign(distance_mm=1000 * results["distance"]).describe()

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
# # Beyond the paper, Table 5: the depth runs of one c* at one noise level
#
# The paper poses the general shift (a, b, c) with depth and solves (a, b) only. Here the training set's
# targets are rebuilt for its points moved by theta* = (a*, b*, c*), noise is drawn as Table 2's (the same
# seeds), and (a, b, c) is trained from (0, 0, 0) with the depth flow (`TrainSettings(fit_depth=True)`;
# docs/method/depth.md). `schedule` is a rule or a schedule `RULE+REFINE:E` (`sdm.train.parse_schedule`):
# the schedule's refinement passes at zoom 0 move c too (`Refinement.moves_c`), where the paper's coarse-to-fine training holds c
# below `TrainSettings.depth_zoom`. The stage `table5` gathers this stage's files.
#
# `sdm.experiments.depth_noise_runs` trains the runs together (each equal to the run trained alone to
# 1e-12 m: the depth flow is a float sum); each row has the fitted (a, b, c), the absolute errors and the
# distances to (a*, b*) and to (a*, b*, c*), in metres.

# %% tags=["parameters"]
sky = "results/sky/sky.bin"  # input
split = "results/split/split.json"  # input
best = "results/tuning/best.json"  # input: the tuned settings (Table 1)
runs_file = "results/research/depth/c1.0_level0.csv"  # output: one row per run
schedule = "closed_centred_r1"  # the gradient rule or schedule of the runs
c = 1.0  # the true depth shift c*, metres
depth_lr_scale = 20.0  # learning rate of c relative to the tuned lr
noise_level = 0  # the noise level
runs = 2  # the runs 0..runs-1 (Table 2's noise seeds for the same indices)
s = 4
batch_size = 16
lr_decay = 0.5
seed = 0  # noise seed (noise.seed): run r at level n draws its noise and shuffling from (seed, n, r)
shift = [0.517, 0.303]  # (a*, b*), metres
threads = 1

# %%
from dataclasses import replace

from IPython.display import display

from sdm.errors import SDMInputError
from sdm.experiments import depth_noise_runs, single_thread, tuned_training
from sdm.experiments.report.io import read_json, write_csv
from sdm.train import parse_schedule

single_thread(threads)
train_set, camera, settings = tuned_training(sky, read_json(split), read_json(best), s, batch_size, lr_decay, seed)
print(f"{len(train_set)} training configurations; n_epoch {settings.n_epoch}, lr {settings.lr:g}, rule {schedule}")

# %%
run_indices = list(range(runs))
rule, refine = parse_schedule(schedule)
depth_settings = replace(settings, rule=rule, depth_lr_scale=depth_lr_scale)
try:
    results = depth_noise_runs(train_set, c, noise_level, run_indices, depth_settings, shift=shift, camera=camera,
                               refine=refine)
except SDMInputError as error:
    if str(error).startswith("c = "):  # the config's c* itself is impossible for these points
        raise SDMInputError(f"config key 'research.depth.shifts_c': {error}") from None
    raise
write_csv(runs_file, results)
print(f"level {noise_level}, runs 0..{runs - 1}: mean distance {1000 * results['distance'].mean():.3f}e-3 m")
display(results.drop(columns=["seed"]).describe())

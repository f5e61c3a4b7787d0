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
# # Stage 3: build the Sky dataset
#
# For every sampled image (paper, section 3; docs/method/paper.md, Geometry):
#
# 1. **E**: the car centres rendered with rmin (r = depth) on the 128 x 256 screen;
# 2. **E'**: a disc of radius 3 ln 4 (57 pixels) around each active pixel of E, the nearest car winning;
# 3. **Q**: one 3D point per active pixel of E' (the pixel centre back-projected at its depth);
# 4. **L**, the target: the occupancy of Q moved by theta* = (a, b, 0).
#
# The solver sees Q and L, never the shift. The construction is `sdm.experiments.data.build_configurations` (one
# `sdm.sky.build_configuration` per image); the file is written by `sdm.experiments.data.write_sky_file`.

# %% tags=["parameters"]
annotations = "results/data/synthetic_apollo"  # folder or csv
source_kind = "synthetic"
sample = "results/sample/sample.csv"  # input: the sampled images
shift = [0.517, 0.303]
sky = "results/sky/sky.bin"  # output: the Sky dataset
stats = "results/sky/stats.json"  # output: its statistics
threads = 1

# %%
import matplotlib.pyplot as plt

from sdm.experiments.data import build_configurations, read_annotations, write_sky_file
from sdm.experiments.data.stats import PAPER_TARGET_DEPTH, configuration_table, summarize
from sdm.experiments import single_thread
from sdm.experiments.report.io import read_csv, write_json

single_thread(threads)
cars_by_image, camera = read_annotations(source_kind, annotations)
by_id = {image.image_id: image for image in cars_by_image}
chosen = [by_id[image_id] for image_id in read_csv(sample, dtype={"image_id": str})["image_id"]]
configurations = build_configurations(chosen, shift=tuple(shift), camera=camera, progress=False)
write_sky_file(sky, configurations, tuple(shift), camera, metadata={"sample": sample, "source": source_kind})
print(f"{len(configurations)} configurations written to {sky}")

# %% [markdown]
# The Sky data's statistics. `target_mean_depth` (the mean depth of the target points) decides Table 2's
# "Avg. Dist." column; the paper's column implies 50.95 m on ApolloCar3D.

# %%
summary = summarize(chosen, configurations, camera)
table = configuration_table(configurations, camera)
summary |= {
    "configurations": len(configurations),
    "empty_configurations": int((table["n_points"] == 0).sum()),
    "target_pixels_per_configuration": float(table["n_target"].mean()),
    "paper_target_mean_depth": PAPER_TARGET_DEPTH,
}
write_json(stats, summary)
summary

# %%
fig, axes = plt.subplots(1, 3, figsize=(14, 3.5), constrained_layout=True)
axes[0].hist(table["n_circles"], bins=40)
axes[0].set_xlabel("circles per configuration")
axes[1].hist(table["n_points"], bins=40)
axes[1].set_xlabel("points (active pixels of E') per configuration")
axes[2].hist(table["n_target"], bins=40)
axes[2].set_xlabel("target pixels per configuration")
plt.show()

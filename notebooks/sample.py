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
# # Stage 2: sample the images of the Sky dataset
#
# "The Sky dataset is built only upon 3D annotations of their 4,248 images which are chosen randomly"
# (paper, section 3). The sample is drawn with `sdm.experiments.data.sample_indices` (the sampling of
# `sdm.experiments.data.build_sky_dataset`) from the seed in the config.

# %% tags=["parameters"]
images = "results/data/images.csv"  # input: one row per image
sample = "results/sample/sample.csv"  # output: the sampled images
n_images = 4248
seed = 0
threads = 1

# %%

from sdm.experiments.data import sample_indices
from sdm.experiments.report.io import read_csv, write_csv

table = read_csv(images)
chosen = table.iloc[sample_indices(len(table), n_images, seed, n_sample_name="config key 'sky.n_images'",
                                   seed_name="config key 'sky.seed'")].reset_index(drop=True)
write_csv(sample, chosen)
print(f"sampled {len(chosen)} of {len(table)} images (seed {seed})")
print(f"cars per image: all {table['n_cars'].mean():.2f}, sample {chosen['n_cars'].mean():.2f}; "
      f"on screen: all {table['n_on_screen'].mean():.2f}, sample {chosen['n_on_screen'].mean():.2f}")
chosen.head()

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
# # Stage 4: train and dev sets
#
# "I split randomly 768 configurations of the Sky dataset, which were chosen randomly, into two datasets
# ... the train set has 512 configurations for training and the dev set has 256 configurations for
# validation" (paper, section 5). Indices refer to the Sky file's order.

# %% tags=["parameters"]
sky = "results/sky/sky.bin"  # input
split = "results/split/split.json"  # output
n_selected = 768
n_train = 512
n_dev = 256
seed = 0
threads = 1

# %%
from sdm.experiments.data import SkyFile
from sdm.experiments import split_indices
from sdm.experiments.report.io import write_json

dataset = SkyFile(sky)
assert n_train + n_dev == n_selected
chosen = split_indices(len(dataset), n_train, n_dev, seed)
ids = dataset.image_ids
write_json(split, {
    "seed": seed,
    "n_sky": len(dataset),
    **chosen,
    "train_ids": [ids[i] for i in chosen["train"]],
    "dev_ids": [ids[i] for i in chosen["dev"]],
})
for name in ("train", "dev"):
    points = [dataset[i].num_points for i in chosen[name]]
    print(f"{name}: {len(points)} configurations, {sum(points) / len(points):.1f} points each on average, "
          f"{sum(p == 0 for p in points)} empty")

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
# # Stage 0: a synthetic ApolloCar3D
#
# ApolloCar3D cannot be downloaded here, so the default input is a synthetic annotation set written in
# ApolloCar3D's own layout (`car_poses/<image>.json`, `camera/Camera_5.txt`). Its scenes are cars on a
# road plane seen from a roof-mounted camera, calibrated on the real figures the paper gives
# (docs/method/paper.md) (over 60K cars on 5,277 images, a mean target depth of about 51 m; docs/method/paper.md, Real layouts and the synthetic default).
# The generator is `sdm.experiments.data.write_synthetic_apollo`; this notebook only runs it and looks at what it wrote.
# With `data.source: apollo` or `pku` in `config.yaml` this stage does not run.

# %% tags=["parameters"]
folder = "results/data/synthetic_apollo"  # output folder
n_images = 5277
seed = 0
threads = 1

# %%
import json

from sdm.experiments.data.synthetic import write_synthetic_apollo
from sdm.experiments import single_thread

single_thread(threads)
path = write_synthetic_apollo(folder, n_images=n_images, seed=seed, overwrite=True)

# %% [markdown]
# What was written: one JSON file per image and the intrinsics, plus the generator's provenance.

# %%
provenance = json.loads((path / "synthetic.json").read_text())
print(f"{provenance['n_images']} images, {provenance['n_cars']} cars "
      f"({provenance['n_cars'] / provenance['n_images']:.2f} per image), seed {provenance['seed']}")
print((path / "camera" / "Camera_5.txt").read_text())
example = sorted((path / "car_poses").glob("*.json"))[0]
print(example.name)
print(example.read_text()[:600])

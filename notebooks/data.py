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
# # Stage 1: the car annotations
#
# Reads the annotations the Sky dataset is built on (paper, section 3): an ApolloCar3D folder (real or
# synthetic) or the PKU/Baidu car-pose `train.csv`. Only each car's centre `(x, y, z)` in the camera frame
# matters. This notebook describes the set: cars per image, how many land on the 128 x 256 screen
# (the lower half of the image), their depths, and the road plane they sit on.

# %% tags=["parameters"]
annotations = "results/data/synthetic_apollo"  # folder or csv
source_kind = "synthetic"  # synthetic | apollo | pku
images = "results/data/images.csv"  # output: one row per image
summary = "results/data/summary.json"  # output: statistics
threads = 1

# %%
import matplotlib.pyplot as plt

from sdm.experiments.data import read_annotations, require_cars_on_screen
from sdm.experiments.data.stats import PAPER_CARS_PER_IMAGE, car_table, fit_road_plane, image_table
from sdm.experiments import single_thread
from sdm.experiments.report.io import write_csv, write_json

single_thread(threads)
cars_by_image, camera = read_annotations(source_kind, annotations)
# Stop here, naming the folder/file, if no image has a car on the screen: every configuration would be empty.
require_cars_on_screen(cars_by_image, camera, source=annotations)
print(f"{len(cars_by_image)} images from {annotations} ({source_kind}); camera {camera}")

# %%
per_image = image_table(cars_by_image, camera)
cars = car_table(cars_by_image, camera)
front = cars[cars["z"] > 0]
plane = fit_road_plane(cars_by_image)
stats = {
    "source": source_kind,
    "images": len(per_image),
    "cars": int(per_image["n_cars"].sum()),
    "cars_per_image": float(per_image["n_cars"].mean()),
    "on_screen_per_image": float(per_image["n_on_screen"].mean()),
    "images_without_car_on_screen": int((per_image["n_on_screen"] == 0).sum()),
    "mean_car_depth": float(front["z"].mean()),
    "median_car_depth": float(front["z"].median()),
    **{f"plane_{key}": value for key, value in plane.items()},
}
write_csv(images, per_image)
write_json(summary, stats)
print(f"ApolloCar3D for comparison: about {PAPER_CARS_PER_IMAGE} cars per image")
stats

# %%
fig, axes = plt.subplots(1, 3, figsize=(14, 3.5), constrained_layout=True)
axes[0].hist(per_image["n_cars"], bins=range(0, int(per_image["n_cars"].max()) + 2), color="#1f77b4")
axes[0].set_xlabel("cars per image")
axes[1].hist(front["z"], bins=60, color="#ff7f0e")
axes[1].set_xlabel("car depth z (m)")
axes[2].scatter(front["z"], front["y"], s=1, alpha=0.2)
axes[2].set_xlabel("z (m)")
axes[2].set_ylabel("y (m, down)")
axes[2].set_title(f"road plane: y = {plane['h']:.2f} + {plane['s_x']:.3f} x + {plane['s_z']:.3f} z")
plt.show()

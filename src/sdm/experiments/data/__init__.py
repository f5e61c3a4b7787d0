"""Data layer: annotation readers, the synthetic ApolloCar3D default, the Sky dataset file.

See ``docs/data.md``. Public API::

    ImageCars(image_id, centres)                       # (M, 3) float64 camera-frame metres
    read_apollo_folder(folder, camera_file=None)       # -> list[ImageCars], sorted by id
    read_apollo_camera(folder)                         # -> Camera
    read_pku_csv(path)                                 # -> list[ImageCars], sorted by id
    write_synthetic_apollo(folder, n_images=5277, seed=0)  # -> Path
    build_sky_dataset(images, n_sample=4248, seed=0, shift=SKY_SHIFT, camera=APOLLO_CAMERA_5, progress=True)
    build_configurations(images, shift=SKY_SHIFT, camera=APOLLO_CAMERA_5, progress=True)  # no sampling
    images_with_cars(n_images, n_cars, seed=0)         # -> list[ImageCars], exactly n_cars visible cars each
    set_with_cars(n_images, n_cars, seed=0, shift=SKY_SHIFT)  # -> ConfigurationSet of those, with its car index
    write_sky_file(path, configurations, shift, camera, metadata=None)
    SkyFile(path, checksums=True)                      # lazy, verified: len, [i], image_ids, shift, camera, load_all()
    require_cars_on_screen(images, camera, source)     # SDMInputError naming source if no image has a car on screen
"""
from .dataset import SKY_N_IMAGES, build_configurations, build_sky_dataset, sample_indices, set_with_cars
from .readers import (
    SOURCE_KINDS, ImageCars, read_annotations, read_apollo_camera, read_apollo_folder, read_car_poses, read_pku_csv,
)
from .skyfile import FORMAT_VERSION, SkyFile, write_sky_file
from .stats import require_cars_on_screen
from .scene import DEFAULT_MODEL, SceneModel
from .synthetic import images_with_cars, synthetic_images, write_synthetic_apollo

__all__ = [
    "DEFAULT_MODEL",
    "FORMAT_VERSION",
    "ImageCars",
    "SKY_N_IMAGES",
    "SceneModel",
    "SkyFile",
    "build_configurations",
    "build_sky_dataset",
    "images_with_cars",
    "read_apollo_camera",
    "read_apollo_folder",
    "read_car_poses",
    "read_pku_csv",
    "read_annotations",
    "require_cars_on_screen",
    "SOURCE_KINDS",
    "sample_indices",
    "set_with_cars",
    "synthetic_images",
    "write_sky_file",
    "write_synthetic_apollo",
]

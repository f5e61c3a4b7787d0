"""Sampling images and building the Sky dataset's configurations (paper, section 3; docs/method/paper.md, Experiments)."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
# tqdm.std, not tqdm.auto: the text bar renders in a notebook too, without auto's "IProgress not found" warning
from tqdm.std import tqdm

from ...batch import ConfigurationSet
from ...camera import APOLLO_CAMERA_5, Camera
from ...errors import SDMInputError
from ...sky import CIRCLE_RADIUS, SKY_SHIFT, SkyConfiguration, build_configuration
from .readers import ImageCars
from .scene import DEFAULT_MODEL, SceneModel
from .synthetic import images_with_cars

#: Number of images of the Sky dataset.
SKY_N_IMAGES = 4248


def sample_indices(n_images: int, n_sample: int, seed: int = 0, *, n_sample_name: str = "n_sample",
                   seed_name: str = "seed") -> np.ndarray:
    """A seeded sample without replacement of ``n_sample`` indices out of ``n_images``.

    Drawn with ``numpy.random.Generator(PCG64(seed)).choice(n_images, n_sample,
    replace=False)`` and returned sorted (int64), so the sample keeps the input order.

    Args:
        n_sample_name, seed_name: how error messages name the two values; a
            caller that took them from a config passes the keys (e.g.
            ``"config key 'sky.n_images'"``) so that the message names them.

    Raises:
        SDMInputError: ``n_sample`` negative, not an integer or larger than
            ``n_images`` ("n_sample = 128 is larger than the number of images
            (57)"); a negative or non-integer seed.
    """
    if isinstance(n_sample, bool) or not isinstance(n_sample, (int, np.integer)) or n_sample < 0:
        raise SDMInputError(f"{n_sample_name} must be a non-negative integer, got {n_sample!r}")
    if n_sample > n_images:
        raise SDMInputError(f"{n_sample_name} = {n_sample} is larger than the number of images ({n_images})")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SDMInputError(f"{seed_name} must be a non-negative integer, got {seed!r}")
    rng = np.random.Generator(np.random.PCG64(int(seed)))
    return np.sort(rng.choice(n_images, size=int(n_sample), replace=False)).astype(np.int64)


def build_sky_dataset(
    images: Sequence[ImageCars],
    n_sample: int = SKY_N_IMAGES,
    seed: int = 0,
    shift: tuple[float, float] = SKY_SHIFT,
    camera: Camera = APOLLO_CAMERA_5,
    progress: bool = True,
    *,
    n_sample_name: str = "n_sample",
    seed_name: str = "seed",
) -> list[SkyConfiguration]:
    """Sample images and build their Sky configurations.

    Args:
        images: the annotation set (e.g. from :func:`~sdm.experiments.data.read_apollo_folder`).
        n_sample: number of images to sample (4,248 in the paper); at most ``len(images)``.
        seed: seed of the sample (see :func:`sample_indices`).
        shift: the true shift ``(a, b)`` in metres.
        camera: camera and screen.
        progress: show a progress bar (tqdm, on stderr).
        n_sample_name, seed_name: how error messages name ``n_sample`` and
            ``seed`` (see :func:`sample_indices`).

    Returns:
        ``n_sample`` configurations, in the order of ``images`` (sorted sample
        indices). An image with no car on screen gives an empty configuration.

    Raises:
        SDMInputError: ``n_sample`` larger than ``len(images)`` or negative, a
            bad seed, an element that is not :class:`ImageCars`.
    """
    images = list(images)
    chosen = sample_indices(len(images), n_sample, seed, n_sample_name=n_sample_name, seed_name=seed_name)
    return build_configurations([images[index] for index in chosen.tolist()], shift, camera, progress)


def build_configurations(
    images: Sequence[ImageCars],
    shift: tuple[float, float] = SKY_SHIFT,
    camera: Camera = APOLLO_CAMERA_5,
    progress: bool = True,
    radius: float = CIRCLE_RADIUS,
) -> list[SkyConfiguration]:
    """One Sky configuration per image, in the given order (no sampling: the images are already chosen).

    Args:
        images: the images, e.g. the workflow's sample (:func:`sample_indices` of the annotation set).
        shift: the true shift ``(a, b)`` in metres.
        camera: camera and screen.
        progress: show a progress bar (tqdm, on stderr).
        radius: a car's disc radius in screen pixels (:func:`sdm.sky.build_configuration`).

    Returns:
        ``len(images)`` configurations; an image with no car on screen gives an empty configuration.

    Raises:
        SDMInputError: an element that is not :class:`ImageCars`.
    """
    images = list(images)
    for index, image in enumerate(images):
        if not isinstance(image, ImageCars):
            raise SDMInputError(f"images[{index}] must be ImageCars, got {type(image).__name__}")
    return [build_configuration(image.centres, shift, camera, image_id=image.image_id, radius=radius)
            for image in tqdm(images, desc="Sky configurations", unit="image", disable=not progress)]


def set_with_cars(
    n_images: int,
    n_cars: int,
    seed: int = 0,
    shift: tuple[float, float] = SKY_SHIFT,
    camera: Camera = APOLLO_CAMERA_5,
    *,
    model: SceneModel = DEFAULT_MODEL,
    progress: bool = False,
    n_images_name: str = "n_images",
    n_cars_name: str = "n_cars",
    seed_name: str = "seed",
    radius: float = CIRCLE_RADIUS,
) -> ConfigurationSet:
    """Sky configurations of synthetic images with exactly ``n_cars`` visible cars each, packed.

    The images of :func:`~sdm.experiments.data.synthetic.images_with_cars` (same arguments), built with
    :func:`build_configurations` and packed by :meth:`ConfigurationSet.from_configurations`: every
    configuration has ``n_cars`` cars, each owning at least one point, so
    :meth:`ConfigurationSet.car_rows` gives ``n_images * n_cars`` rows.

    Returns:
        A CPU set of ``n_images`` configurations with its car index (:attr:`ConfigurationSet.cars`).

    Raises:
        SDMInputError: as :func:`~sdm.experiments.data.synthetic.images_with_cars`, naming the value.
    """
    images = images_with_cars(n_images, n_cars, seed, model=model, camera=camera, n_images_name=n_images_name,
                              n_cars_name=n_cars_name, seed_name=seed_name)
    return ConfigurationSet.from_configurations(build_configurations(images, shift, camera, progress, radius), camera)

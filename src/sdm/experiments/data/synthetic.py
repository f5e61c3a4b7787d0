"""A synthetic ApolloCar3D: street scenes seen from a roof camera, in ApolloCar3D's own layout.

ApolloCar3D cannot be downloaded here, so the default data source is a seeded
synthetic annotation set written exactly like the real one
(``car_poses/<image>.json`` + ``camera/Camera_5.txt``); the real-data path and
the default path share every line after :func:`~sdm.experiments.data.read_apollo_folder`.

The scene of one image is :mod:`sdm.experiments.data.scene` (:class:`~sdm.experiments.data.scene.SceneModel`).

Calibration (``docs/data.md`` gives the measured numbers): ~11.4 labelled cars
per image (ApolloCar3D: over 60K cars on 5,277 images) and a mean depth of the
Sky target points of ~51 m (docs/method/paper.md, Experiments; Real layouts and the synthetic default), which reproduces
Table 2's "Avg. Dist." column.

Determinism: image ``i`` of seed ``s`` is drawn from
``numpy.random.Generator(PCG64(SeedSequence(s, spawn_key=(i,))))``, so it does
not depend on ``n_images``, and the same seed writes byte-identical files.
"""
from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from ...camera import APOLLO_CAMERA_5, Camera
from ...errors import SDMInputError
from ...io import current_umask
from ...representation import screen_pixels
from ...sky import circle_offsets
from .readers import CAMERA_DIR, CAMERA_FILE, CAR_POSES, ImageCars
from .scene import DEFAULT_MODEL, SceneModel, draw_image, footprint_clash, generate_scene

#: Version of the scene model; written to ``synthetic.json`` in the folder.
GENERATOR_VERSION = 1
#: Provenance file written next to ``car_poses`` and ``camera``.
PROVENANCE_FILE = "synthetic.json"
#: Number of CAD car models in ApolloCar3D (``car_id`` is drawn from 0..78).
N_CAR_MODELS = 79
#: Between two numbers of a pose in the car files (:func:`records_json`): json's comma, newline and indent.
_POSE_SEPARATOR = ",\n" + " " * 12


def image_rng(seed: int, index: int) -> np.random.Generator:
    """The random generator of synthetic image ``index`` under ``seed``."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed, spawn_key=(index,))))


def synthetic_image_id(index: int, n_images: int) -> str:
    """Image id of synthetic image ``index``: ``synthetic_00042_Camera_5`` (zero-padded, sorts numerically)."""
    width = max(5, len(str(max(n_images - 1, 0))))
    return f"synthetic_{index:0{width}d}_Camera_5"


def car_records(cars: np.ndarray, rng: np.random.Generator) -> list[dict]:
    """ApolloCar3D car objects for the ``(M, 8)`` output of :func:`generate_scene`.

    Each is ``{"area", "car_id", "pose", "visible_rate"}`` like the real
    files: ``pose`` is ``[roll, pitch, yaw, x, y, z]``, ``area`` the visible
    area in image pixels, ``car_id`` a random CAD model (0..78); only the
    pose's ``x, y, z`` are used by the Sky construction. Values are rounded to
    6 decimals so the JSON text is short and platform independent.
    """
    records = []
    for car in cars.tolist():  # Python floats, the very values float() of each element gives
        records.append(
            {
                "area": int(round(car[7])),
                "car_id": int(rng.integers(N_CAR_MODELS)),
                "pose": [round(v, 6) for v in car[:6]],
                "visible_rate": round(car[6], 6),
            }
        )
    return records


def records_json(records: list[dict]) -> str:
    """``json.dumps(records, indent=4, sort_keys=True)`` of :func:`car_records`' output, written directly.

    With ``indent`` the standard library encodes in pure Python, a third of the time of writing the default
    5,277 images; this writes the same characters for records of that one form (``area`` and ``car_id`` ints,
    ``pose`` six finite floats, ``visible_rate`` a finite float: keys in sorted order, numbers as ``repr``
    writes them, as :mod:`json` does), and hands anything else to :func:`json.dumps`
    (``tests/experiments/data/test_synthetic_json.py`` holds the two equal).
    """
    cars = []
    for record in records:
        area, car_id, pose, rate = (record.get(key) for key in ("area", "car_id", "pose", "visible_rate"))
        if (len(record) != 4 or type(area) is not int or type(car_id) is not int or type(pose) is not list
                or len(pose) != 6 or type(rate) is not float or not math.isfinite(rate)
                or not all(type(v) is float and math.isfinite(v) for v in pose)):
            return json.dumps(records, indent=4, sort_keys=True)
        cars.append(f'    {{\n        "area": {area!r},\n        "car_id": {car_id!r},\n        "pose": [\n'
                    f'            {_POSE_SEPARATOR.join(map(repr, pose))}\n        ],\n'
                    f'        "visible_rate": {rate!r}\n    }}')
    return "[\n" + ",\n".join(cars) + "\n]" if cars else "[]"


def camera_text(camera: Camera) -> str:
    """ApolloCar3D intrinsics text (``fx = ...;`` lines) for ``camera``."""
    return "".join(f"{key} = {getattr(camera, key)!r};\n" for key in ("fx", "fy", "cx", "cy"))


def write_synthetic_apollo(
    folder: str | Path,
    n_images: int = 5277,
    seed: int = 0,
    *,
    model: SceneModel = DEFAULT_MODEL,
    camera: Camera = APOLLO_CAMERA_5,
    overwrite: bool = False,
) -> Path:
    """Write a synthetic ApolloCar3D annotation folder.

    Writes ``folder/car_poses/<image>.json`` (one JSON list of cars per image,
    ApolloCar3D's format), ``folder/camera/Camera_5.txt`` and
    ``folder/synthetic.json`` (generator version, seed, parameters). The folder
    is assembled in a temporary sibling and renamed into place, so an error
    leaves nothing half-written.

    Args:
        folder: destination; must not exist, be an empty folder, or
            ``overwrite`` must be true.
        n_images: number of images (ApolloCar3D has 5,277).
        seed: random seed; the same seed gives byte-identical files.
        model: scene parameters (defaults are the calibrated ones).
        camera: intrinsics written to ``Camera_5.txt`` (field of view of the scenes).
        overwrite: replace an existing non-empty ``folder``.

    Returns:
        The folder's path.
    """
    folder = Path(folder)
    if isinstance(n_images, bool) or not isinstance(n_images, (int, np.integer)) or n_images < 1:
        raise SDMInputError(f"n_images must be a positive integer, got {n_images!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SDMInputError(f"seed must be a non-negative integer, got {seed!r}")
    if folder.exists():
        if not folder.is_dir():
            raise SDMInputError(f"{folder}: exists and is not a folder")
        if any(folder.iterdir()) and not overwrite:
            raise SDMInputError(f"{folder}: folder exists and is not empty (pass overwrite=True to replace it)")
    folder.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".tmp", dir=folder.parent))
    try:
        poses_dir = staging / CAR_POSES
        poses_dir.mkdir()
        total = 0
        for index in range(int(n_images)):
            rng = image_rng(int(seed), index)
            poses = draw_image(rng, model, camera)
            total += poses.shape[0]
            text = records_json(car_records(poses, rng))
            (poses_dir / f"{synthetic_image_id(index, n_images)}.json").write_text(text + "\n", encoding="utf-8")
        (staging / CAMERA_DIR).mkdir()
        (staging / CAMERA_DIR / CAMERA_FILE).write_text(camera_text(camera), encoding="utf-8")
        provenance = {
            "generator": "sdm.experiments.data.synthetic",
            "generator_version": GENERATOR_VERSION,
            "seed": int(seed),
            "n_images": int(n_images),
            "n_cars": int(total),
            "model": asdict(model),
            "camera": asdict(camera),
        }
        (staging / PROVENANCE_FILE).write_text(json.dumps(provenance, indent=2, sort_keys=True) + "\n", encoding="utf-8")
        os.chmod(staging, 0o777 & ~current_umask())  # mkdtemp made it 0700; a plain mkdir would honour the umask
        if folder.exists():
            trash = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".old", dir=folder.parent))
            os.replace(folder, trash / "old")
            os.replace(staging, folder)
            shutil.rmtree(trash, ignore_errors=True)
        else:
            os.replace(staging, folder)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return folder


def synthetic_images(
    n_images: int, seed: int = 0, *, model: SceneModel = DEFAULT_MODEL, camera: Camera = APOLLO_CAMERA_5
) -> list[ImageCars]:
    """The synthetic images in memory, as :func:`read_apollo_folder` would read them back.

    Same scenes (and the same 6-decimal rounding) as :func:`write_synthetic_apollo`
    with the same ``n_images`` and ``seed``, without touching the disk: for
    calibration and quick experiments. Returns a list of :class:`ImageCars`.
    """
    images = []
    for index in range(int(n_images)):
        rng = image_rng(int(seed), index)
        poses = draw_image(rng, model, camera)
        records = car_records(poses, rng)
        centres = torch.tensor([r["pose"][3:] for r in records], dtype=torch.float64).reshape(-1, 3)
        images.append(ImageCars(synthetic_image_id(index, n_images), centres))
    return images


# -- images with a given number of visible cars -------------------------------------------------

#: Scenes :func:`images_with_cars` draws at most for one image before it gives up.
MAX_SCENES_PER_IMAGE = 200


def images_with_cars(
    n_images: int,
    n_cars: int,
    seed: int = 0,
    *,
    model: SceneModel = DEFAULT_MODEL,
    camera: Camera = APOLLO_CAMERA_5,
    n_images_name: str = "n_images",
    n_cars_name: str = "n_cars",
    seed_name: str = "seed",
) -> list[ImageCars]:
    """Synthetic images with exactly ``n_cars`` cars each, every one of them visible in the Sky data.

    For experiments that vary the number of unknowns per configuration. An image's cars are
    drawn from the default scene model (:func:`generate_scene`: realistic depths, lanes and road
    planes), the labelled cars of one scene in random order, then those of the next scene, until
    ``n_cars`` are kept. A car is kept when, with the cars kept before it:

    * its centre is in front of the camera and falls on a pixel of the Sky screen (``E``) that no
      kept car holds;
    * its depth equals no kept car's (no tie for the ``rmin`` rule to break);
    * its footprint on the road overlaps no kept car's (cars of different scenes may meet);
    * it owns at least one point of ``E'`` (its circle is not hidden by nearer ones), and every
      kept car still does.

    So :func:`sdm.sky.build_configuration` of an image gives ``n_cars`` cars (centres of ``E``),
    each owning at least one point (:attr:`sdm.sky.SkyConfiguration.cars`). Up to about 11 cars
    (the default model's mean) an image's cars mostly come from one scene; more cars mix scenes.

    Determinism: image ``i`` draws from ``numpy.random.Generator(PCG64(SeedSequence(seed,
    spawn_key=(n_cars, i))))``, so it depends on neither ``n_images`` nor the other car counts.
    Centres are rounded to 6 decimals, like :func:`synthetic_images`.

    Args:
        n_images: number of images, a positive integer.
        n_cars: cars per image, a positive integer.
        seed: a non-negative integer.
        model: scene parameters (defaults are the calibrated ones).
        camera: camera and screen.
        n_images_name, n_cars_name, seed_name: how error messages name the three values (a caller
            that read them from a config passes the keys).

    Returns:
        ``n_images`` :class:`ImageCars`, ids ``cars<n_cars>_<i>`` (zero-padded), each with
        ``(n_cars, 3)`` float64 centres sorted by depth.

    Raises:
        SDMInputError: naming the value, unless ``n_images`` and ``n_cars`` are positive integers and
            ``seed`` a non-negative one; naming ``n_cars`` when an image cannot hold that many
            visible cars (:data:`MAX_SCENES_PER_IMAGE` scenes drawn without reaching it).
    """
    for value, name, low in ((n_images, n_images_name, 1), (n_cars, n_cars_name, 1), (seed, seed_name, 0)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            kind = "positive" if low else "non-negative"
            raise SDMInputError(f"{name} must be a {kind} integer, got {value!r}")
    width = max(5, len(str(int(n_images) - 1)))
    images = []
    for index in range(int(n_images)):
        rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(int(seed), spawn_key=(int(n_cars), index))))
        centres = _visible_cars(rng, int(n_cars), model, camera)
        if centres is None:
            raise SDMInputError(
                f"{n_cars_name} = {n_cars}: image {index} could not hold {n_cars} visible cars on the "
                f"{camera.screen_height}x{camera.screen_width} Sky screen ({MAX_SCENES_PER_IMAGE} scenes drawn)"
            )
        images.append(ImageCars(f"cars{int(n_cars):02d}_{index:0{width}d}", centres))
    return images


def _visible_cars(rng: np.random.Generator, n_cars: int, model: SceneModel, camera: Camera) -> torch.Tensor | None:
    """``(n_cars, 3)`` float64 centres sorted by depth kept as :func:`images_with_cars` says, or None.

    Keeps ``E'`` (nearest depth per screen pixel) and its owner up to date car by car, so a
    candidate costs one disc (57 pixels), not a new configuration.
    """
    height, width = camera.screen_shape
    offsets = circle_offsets().numpy()
    depth = np.full((height, width), np.inf)  # E' so far
    owner = np.full((height, width), -1, dtype=np.int64)  # which kept car painted it
    owned: list[int] = []  # pixels each kept car owns
    kept: list[np.ndarray] = []  # rows [x, y, z, yaw]
    centre_cells: set[tuple[int, int]] = set()
    for _ in range(MAX_SCENES_PER_IMAGE):
        cars = generate_scene(rng, model, camera)
        if cars.shape[0] == 0:
            continue
        cars = cars[rng.permutation(cars.shape[0])]
        xyz = np.round(cars[:, 3:6], 6)
        front = xyz[:, 2] > 0
        pixels = np.zeros((xyz.shape[0], 2), dtype=np.int64)
        on_screen = np.zeros(xyz.shape[0], dtype=bool)
        if front.any():  # the projection of render_centres (sdm.sky): the same pixel of E
            found, inside = screen_pixels(camera.project(torch.from_numpy(xyz[front])), camera)
            pixels[front], on_screen[front] = found.numpy(), inside.numpy()
        for k in np.flatnonzero(on_screen):
            row, col = (int(v) for v in pixels[k])
            z = float(xyz[k, 2])
            if (row, col) in centre_cells or any(z == car[2] for car in kept):
                continue
            if kept:
                table = np.array(kept + [np.array([*xyz[k], cars[k, 2]])])
                if footprint_clash(table[:, 0], table[:, 2], table[:, 3], model)[-1, :-1].any():
                    continue
            disc = offsets + (row, col)
            disc = disc[(disc[:, 0] >= 0) & (disc[:, 0] < height) & (disc[:, 1] >= 0) & (disc[:, 1] < width)]
            wins = z < depth[disc[:, 0], disc[:, 1]]
            if not wins.any():
                continue  # hidden behind nearer circles
            taken = disc[wins]
            losers = owner[taken[:, 0], taken[:, 1]]
            lost = np.bincount(losers[losers >= 0], minlength=len(owned))
            if any(have - gone <= 0 for have, gone in zip(owned, lost)):
                continue  # it would hide a kept car entirely
            owned = [have - gone for have, gone in zip(owned, lost)] + [int(wins.sum())]
            depth[taken[:, 0], taken[:, 1]] = z
            owner[taken[:, 0], taken[:, 1]] = len(kept)
            kept.append(np.array([*xyz[k], cars[k, 2]]))
            centre_cells.add((row, col))
            if len(kept) == n_cars:
                table = np.array(kept)[:, :3]
                return torch.from_numpy(table[np.argsort(table[:, 2], kind="stable")].copy())
    return None

"""A synthetic ApolloCar3D: street scenes seen from a roof camera, in ApolloCar3D's own layout.

ApolloCar3D cannot be downloaded here, so the default data source is a seeded
synthetic annotation set written exactly like the real one
(``car_poses/<image>.json`` + ``camera/Camera_5.txt``); the real-data path and
the default path share every line after :func:`~sdm.data.read_apollo_folder`.

Scene model (one image; every number below is a field of :class:`SceneModel`)
------------------------------------------------------------------------------
* **Road plane.** Cars sit on the plane ``y = h + s_x x + s_z z`` (camera frame,
  metres) fitted to the real ApolloCar3D sample (``h = 1.12``, ``s_x = 0.05``,
  ``s_z = 0.17``: the camera is mounted ~1.1 m above the car centres and the
  road rises ~0.17 m per metre ahead in its frame), jittered per image (the
  road's grade and the car's pitch change), plus a per-car residual like the
  sample's (0.2 m).
* **Road.** 1-3 lanes in the driving direction, 0-3 oncoming lanes on the
  left behind a median, lane width 3.2-3.8 m, the camera car in one of its
  lanes; the road may curve (``x`` gains ``kappa z^2 / 2``).
* **Traffic.** Each lane is filled by a renewal process along ``z``: car
  length 4.2-5.0 m, bumper-to-bumper gap at least ``min_gap`` (5 m) plus an
  exponential headway whose mean falls with a per-image traffic density, so
  cars in a lane never interpenetrate. The lane ahead of the camera starts
  beyond ``ego_clearance``. Traffic runs to a per-image range (``max_depth``).
* **Parked rows** at one or both kerbs (probability ``p_parked``), bumper to
  bumper with 0.5-2.5 m gaps and random holes.
* **Cross street** (probability ``p_cross``): an intersection ahead with cars
  crossing on two lanes. Cars whose footprints overlap an earlier car are dropped.
* **Labelling.** As in ApolloCar3D, only cars visible enough are labelled:
  each car's 3D box is projected into the image and rasterised near to far
  (:func:`_visibility`); a car is labelled when at least ``min_visible`` (30%)
  of it is visible and its visible area is at least ``min_area`` (550 image
  pixels), the smallest values among the real sample's cars. Cars behind the
  camera or outside the image are not labelled; the few labelled cars whose
  centre falls off the Sky screen are dropped by
  :func:`sdm.sky.build_configuration`. A scene with fewer than ``min_cars``
  labelled cars is redrawn (:func:`draw_image`).

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
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from ..camera import APOLLO_CAMERA_5, Camera
from ..errors import SDMInputError
from ..io import current_umask
from ..representation import screen_pixels
from ..sky import circle_offsets
from .readers import CAMERA_DIR, CAMERA_FILE, CAR_POSES, ImageCars

#: Version of the scene model; written to ``synthetic.json`` in the folder.
GENERATOR_VERSION = 1
#: Provenance file written next to ``car_poses`` and ``camera``.
PROVENANCE_FILE = "synthetic.json"
#: Number of CAD car models in ApolloCar3D (``car_id`` is drawn from 0..78).
N_CAR_MODELS = 79


@dataclass(frozen=True)
class SceneModel:
    """Parameters of the synthetic street scenes (metres, radians, probabilities).

    The defaults are the calibrated ones; see the module docstring.
    """

    # road plane y = h + s_x x + s_z z, fitted to the real sample
    plane_height: float = 1.12
    plane_slope_x: float = 0.05
    plane_slope_z: float = 0.17
    plane_height_jitter: float = 0.10
    plane_slope_x_jitter: float = 0.02
    plane_slope_z_jitter: float = 0.015
    car_height_noise: float = 0.20
    # road layout
    lane_width: tuple[float, float] = (3.2, 3.8)
    same_lanes_p: tuple[float, float, float] = (0.25, 0.45, 0.30)  # 1, 2, 3 lanes
    oncoming_lanes_p: tuple[float, float, float, float] = (0.20, 0.30, 0.35, 0.15)  # 0..3 lanes
    median: tuple[float, float] = (0.0, 3.0)
    ego_offset_sd: float = 0.3
    curvature_sd: float = 1e-3
    # traffic
    car_length: tuple[float, float] = (4.2, 5.0)
    car_width: float = 1.8
    min_gap: float = 5.0
    headway_mean: float = 22.0  # mean extra gap at density 1
    density_shape: float = 2.0  # gamma shape of the per-image traffic density (mean 1)
    ego_clearance: tuple[float, float] = (9.0, 18.0)
    p_no_lead: float = 0.3  # probability of no car right ahead (first car a headway further)
    max_depth: tuple[float, float] = (160.0, 240.0)
    start_depth: float = -5.0
    # parked rows
    p_parked: float = 0.35
    kerb_offset: tuple[float, float] = (1.2, 2.5)  # from the outer lane edge to the parked car centre
    parked_gap: tuple[float, float] = (0.5, 2.5)
    parked_hole_p: float = 0.3
    parked_hole: tuple[float, float] = (5.0, 25.0)
    # cross street
    p_cross: float = 0.4
    cross_depth: tuple[float, float] = (25.0, 90.0)
    cross_extent: float = 40.0
    # labelling: cars that are visible enough and large enough in the image
    car_height: float = 1.5
    box_fill: float = 0.8  # visible area = box_fill x visible box area
    occluder_fill: float = 0.9  # a car hides this central fraction of its box
    min_visible: float = 0.3
    min_area: float = 550.0
    min_cars: int = 1  # labelled cars per image at least (scenes are redrawn)
    # orientation of the car relative to the camera (written, not used by the Sky construction)
    roll: float = 0.155
    pitch: float = 0.04


DEFAULT_MODEL = SceneModel()
#: Attempts of :func:`draw_image` to reach ``min_cars``.
MAX_REDRAWS = 50
#: Coarseness of the occlusion grid (image pixels per cell side).
VIS_SCALE = 8


def generate_scene(rng: np.random.Generator, model: SceneModel = DEFAULT_MODEL, camera: Camera = APOLLO_CAMERA_5) -> np.ndarray:
    """Draw the labelled cars of one synthetic image.

    Args:
        rng: the image's random generator.
        model: scene parameters.
        camera: used for the field of view (cars outside the image are not labelled).

    Returns:
        ``(M, 8)`` float64 rows ``[roll, pitch, yaw, x, y, z, visible_rate, area]``
        (radians, metres, fraction, image pixels) of the labelled cars, sorted
        by ``z``; ``M`` may be 0.
    """
    m = model
    # road plane and curve
    h = m.plane_height + m.plane_height_jitter * rng.standard_normal()
    sx = m.plane_slope_x + m.plane_slope_x_jitter * rng.standard_normal()
    sz = m.plane_slope_z + m.plane_slope_z_jitter * rng.standard_normal()
    kappa = m.curvature_sd * rng.standard_normal()
    width = rng.uniform(*m.lane_width)
    n_same = 1 + int(rng.choice(len(m.same_lanes_p), p=m.same_lanes_p))
    n_oncoming = int(rng.choice(len(m.oncoming_lanes_p), p=m.oncoming_lanes_p))
    ego = int(rng.integers(n_same))
    offset = m.ego_offset_sd * rng.standard_normal()
    median = rng.uniform(*m.median) if n_oncoming else 0.0
    density = rng.gamma(m.density_shape, 1.0 / m.density_shape)
    max_depth = rng.uniform(*m.max_depth)

    # lateral positions (x at z = 0) and directions (+1 same as camera, -1 oncoming)
    same_x = [(k - ego) * width + offset for k in range(n_same)]
    left_edge = same_x[0] - width / 2
    oncoming_x = [left_edge - median - (k + 0.5) * width for k in range(n_oncoming)]
    lanes = [(x, +1) for x in same_x] + [(x, -1) for x in oncoming_x]

    cars: list[tuple[float, float, float]] = []  # (x0, z, heading)
    for index, (x0, direction) in enumerate(lanes):
        if direction > 0 and index == ego:
            z = rng.uniform(*m.ego_clearance)
            if rng.random() < m.p_no_lead:
                z += rng.exponential(m.headway_mean / density)
        else:
            z = m.start_depth + rng.uniform(0.0, m.min_gap + m.car_length[1])
        while z < max_depth:
            cars.append((x0 + 0.15 * rng.standard_normal(), z, 0.0 if direction > 0 else math.pi))
            length = rng.uniform(*m.car_length)
            z += length + m.min_gap + rng.exponential(m.headway_mean / density)

    # parked rows at the kerbs
    kerbs = [(same_x[-1] + width / 2, +1.0, 0.0)]
    outer_left = oncoming_x[-1] - width / 2 if n_oncoming else left_edge
    kerbs.append((outer_left, -1.0, math.pi if n_oncoming else 0.0))
    for edge, side, heading in kerbs:
        if rng.random() >= m.p_parked:
            continue
        x0 = edge + side * rng.uniform(*m.kerb_offset)
        z = m.start_depth + rng.uniform(0.0, 8.0)
        row_end = rng.uniform(20.0, max_depth)
        while z < row_end:
            if rng.random() < m.parked_hole_p:
                z += rng.uniform(*m.parked_hole)
                continue
            cars.append((x0 + 0.1 * rng.standard_normal(), z, heading + 0.05 * rng.standard_normal()))
            z += rng.uniform(*m.car_length) + rng.uniform(*m.parked_gap)

    poses = []
    for x0, z, heading in cars:
        x = x0 + 0.5 * kappa * z * z
        poses.append((x, z, heading + kappa * z))

    # cross street: cars moving across the view on two lanes
    if rng.random() < m.p_cross:
        z_cross = rng.uniform(*m.cross_depth)
        for side in (-1.0, 1.0):
            z_lane = z_cross + side * width / 2
            x = -m.cross_extent + rng.uniform(0.0, 10.0)
            while x < m.cross_extent:
                poses.append((x, z_lane, side * math.pi / 2))
                x += rng.uniform(*m.car_length) + m.min_gap + rng.exponential(2 * m.headway_mean / density)

    if not poses:
        return np.zeros((0, 8))
    poses = np.array(poses, dtype=np.float64)
    poses = _drop_overlapping(poses, m)
    x, z, heading = poses[:, 0], poses[:, 1], poses[:, 2]
    # in front of the camera and roughly inside the image columns
    half_fov = max(camera.cx, camera.image_width - camera.cx) / camera.fx
    keep = (z > 1.0) & (np.abs(x) < half_fov * z + 3.0)
    x, z, heading = x[keep], z[keep], heading[keep]
    n = x.shape[0]
    y = h + sx * x + sz * z + m.car_height_noise * rng.standard_normal(n)
    order = np.argsort(z, kind="stable")
    x, y, z, heading = x[order], y[order], z[order], heading[order]
    visible, area = _visibility(x, y, z, heading, (sx, sz), m, camera)
    # ApolloCar3D labels the cars that are visible enough and not too small
    labelled = (visible >= m.min_visible) & (area >= m.min_area)
    x, y, z, heading, visible, area = (v[labelled] for v in (x, y, z, heading, visible, area))
    n = x.shape[0]
    # yaw in ApolloCar3D's camera-relative convention: a car driving away is ~ -pi
    yaw = _wrap(heading - math.pi + 0.02 * rng.standard_normal(n))
    roll = m.roll + 0.003 * rng.standard_normal(n)
    pitch = m.pitch + 0.03 * rng.standard_normal(n)
    return np.stack([roll, pitch, yaw, x, y, z, visible, area], axis=1)


def draw_image(rng: np.random.Generator, model: SceneModel = DEFAULT_MODEL, camera: Camera = APOLLO_CAMERA_5) -> np.ndarray:
    """The labelled cars of one synthetic image: :func:`generate_scene`, redrawn until it has ``min_cars`` cars.

    ApolloCar3D's images were chosen for their cars, so by default none is
    empty; a scene is redrawn (from the same generator, so deterministically)
    at most ``MAX_REDRAWS`` times, after which the last draw is kept.
    """
    for _ in range(MAX_REDRAWS):
        cars = generate_scene(rng, model, camera)
        if cars.shape[0] >= model.min_cars:
            break
    return cars


def _visibility(
    x: np.ndarray,
    y: np.ndarray,
    z: np.ndarray,
    heading: np.ndarray,
    slopes: tuple[float, float],
    m: SceneModel,
    camera: Camera,
) -> tuple[np.ndarray, np.ndarray]:
    """Visible fraction and visible area (image pixels) of each car, cars sorted near to far.

    Each car is its image bounding box (the projection of its 3D box:
    footprint ``car_length[1] x car_width`` rotated by ``heading``, height
    ``car_height``, lying on the road plane of slopes ``(s_x, s_z)``), rasterised on an image grid ``VIS_SCALE`` times coarser
    than the image; nearer boxes hide farther ones, and the image border
    truncates them. The visible area is ``box_fill`` times the visible box
    area (a car's mask does not fill its box).
    """
    scale = VIS_SCALE
    grid_h = -(-camera.image_height // scale)
    grid_w = -(-camera.image_width // scale)
    occupied = np.zeros((grid_h, grid_w), dtype=bool)
    n = x.shape[0]
    visible = np.zeros(n)
    area = np.zeros(n)
    if n == 0:
        return visible, area
    half_len, half_wid, half_hgt = m.car_length[1] / 2, m.car_width / 2, m.car_height / 2
    dl = np.array([-half_len, -half_len, half_len, half_len])
    dw = np.array([-half_wid, half_wid, -half_wid, half_wid])
    c, s = np.cos(heading)[:, None], np.sin(heading)[:, None]
    cx = x[:, None] + dl * s + dw * c  # (n, 4) footprint corners
    cz = np.maximum(z[:, None] + dl * c - dw * s, 0.5)
    cy = y[:, None] + slopes[0] * (cx - x[:, None]) + slopes[1] * (cz - z[:, None])  # on the road plane
    u = camera.fx * cx / cz + camera.cx
    u0, u1 = u.min(axis=1), u.max(axis=1)
    v0 = (camera.fy * (cy - half_hgt) / cz + camera.cy).min(axis=1)
    v1 = (camera.fy * (cy + half_hgt) / cz + camera.cy).max(axis=1)
    full = (u1 - u0) * (v1 - v0) / (scale * scale)  # box area in grid cells
    shrink = (1 - math.sqrt(m.occluder_fill)) / 2
    for i in range(n):
        c0, c1 = max(math.floor(u0[i] / scale), 0), min(math.ceil(u1[i] / scale), grid_w)
        r0, r1 = max(math.floor(v0[i] / scale), 0), min(math.ceil(v1[i] / scale), grid_h)
        if c1 <= c0 or r1 <= r0 or full[i] <= 0:
            continue
        window = occupied[r0:r1, c0:c1]
        free = window.size - int(np.count_nonzero(window))
        visible[i] = min(free / max(full[i], window.size), 1.0)
        area[i] = m.box_fill * visible[i] * full[i] * scale * scale
        # the car hides the central part of its box (a silhouette does not fill its box)
        du, dv = shrink * (u1[i] - u0[i]), shrink * (v1[i] - v0[i])
        o0, o1 = max(round((u0[i] + du) / scale), 0), min(round((u1[i] - du) / scale), grid_w)
        q0, q1 = max(round((v0[i] + dv) / scale), 0), min(round((v1[i] - dv) / scale), grid_h)
        occupied[q0:q1, o0:o1] = True
    return visible, area


def _drop_overlapping(poses: np.ndarray, m: SceneModel) -> np.ndarray:
    """Drop cars whose footprint overlaps an earlier one (cross street vs lanes, parked vs lanes).

    Footprints are the axis-aligned boxes (in x, z) of ``car_length[1] x car_width``
    rotated by the heading; greedy in list order.
    """
    clash = _footprint_clash(poses[:, 0], poses[:, 1], poses[:, 2], m)
    keep = np.zeros(poses.shape[0], dtype=bool)
    for i in range(poses.shape[0]):
        keep[i] = not bool((clash[i, :i] & keep[:i]).any())
    return poses[keep]


def _footprint_clash(x: np.ndarray, z: np.ndarray, heading: np.ndarray, m: SceneModel) -> np.ndarray:
    """``(n, n)`` bool: the footprints of cars ``i`` and ``j`` overlap (axis-aligned boxes in x, z).

    A box is ``car_length[1] x car_width`` rotated by the heading; a heading and its opposite
    (a yaw) give the same box.
    """
    c, s = np.abs(np.cos(heading)), np.abs(np.sin(heading))
    half_len, half_wid = m.car_length[1] / 2, m.car_width / 2
    ax = half_len * s + half_wid * c
    az = half_len * c + half_wid * s
    return (np.abs(x[:, None] - x[None, :]) < ax[:, None] + ax[None, :]) & (
        np.abs(z[:, None] - z[None, :]) < az[:, None] + az[None, :]
    )


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + math.pi) % (2 * math.pi) - math.pi


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
    for car in cars:
        records.append(
            {
                "area": int(round(float(car[7]))),
                "car_id": int(rng.integers(N_CAR_MODELS)),
                "pose": [round(float(v), 6) for v in car[:6]],
                "visible_rate": round(float(car[6]), 6),
            }
        )
    return records


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
            text = json.dumps(car_records(poses, rng), indent=4, sort_keys=True)
            (poses_dir / f"{synthetic_image_id(index, n_images)}.json").write_text(text + "\n", encoding="utf-8")
        (staging / CAMERA_DIR).mkdir()
        (staging / CAMERA_DIR / CAMERA_FILE).write_text(camera_text(camera), encoding="utf-8")
        provenance = {
            "generator": "sdm.data.synthetic",
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
                if _footprint_clash(table[:, 0], table[:, 2], table[:, 3], model)[-1, :-1].any():
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

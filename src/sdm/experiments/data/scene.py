"""The synthetic street scene of one image: the labelled cars a roof camera sees (:func:`draw_image`), for
the synthetic ApolloCar3D of :mod:`sdm.experiments.data.synthetic`.

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
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...camera import APOLLO_CAMERA_5, Camera


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
    cars = _lane_cars(rng, m, lanes, ego, density, max_depth)
    # parked rows at the kerbs
    kerbs = [(same_x[-1] + width / 2, +1.0, 0.0)]
    outer_left = oncoming_x[-1] - width / 2 if n_oncoming else left_edge
    kerbs.append((outer_left, -1.0, math.pi if n_oncoming else 0.0))
    cars += _parked_cars(rng, m, kerbs, max_depth)
    poses = [(x0 + 0.5 * kappa * z * z, z, heading + kappa * z) for x0, z, heading in cars]
    poses += _cross_street_cars(rng, m, width, density)
    if not poses:
        return np.zeros((0, 8))
    return _labelled_cars(rng, m, camera, np.array(poses, dtype=np.float64), (h, sx, sz))


def _lane_cars(rng: np.random.Generator, m: SceneModel, lanes: list[tuple[float, int]], ego: int, density: float,
               max_depth: float) -> list[tuple[float, float, float]]:
    """``(x at z = 0, z, heading)`` of the traffic in each lane ``(x, direction)``: a renewal process along ``z``."""
    cars: list[tuple[float, float, float]] = []
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
    return cars


def _parked_cars(rng: np.random.Generator, m: SceneModel, kerbs: list[tuple[float, float, float]],
                 max_depth: float) -> list[tuple[float, float, float]]:
    """``(x at z = 0, z, heading)`` of the parked rows at the kerbs ``(edge, side, heading)`` (each with
    probability ``p_parked``)."""
    cars: list[tuple[float, float, float]] = []
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
    return cars


def _cross_street_cars(rng: np.random.Generator, m: SceneModel, width: float,
                       density: float) -> list[tuple[float, float, float]]:
    """``(x, z, heading)`` of the cars crossing the view on two lanes (with probability ``p_cross``)."""
    poses: list[tuple[float, float, float]] = []
    if rng.random() < m.p_cross:
        z_cross = rng.uniform(*m.cross_depth)
        for side in (-1.0, 1.0):
            z_lane = z_cross + side * width / 2
            x = -m.cross_extent + rng.uniform(0.0, 10.0)
            while x < m.cross_extent:
                poses.append((x, z_lane, side * math.pi / 2))
                x += rng.uniform(*m.car_length) + m.min_gap + rng.exponential(2 * m.headway_mean / density)
    return poses


def _labelled_cars(rng: np.random.Generator, m: SceneModel, camera: Camera, poses: np.ndarray,
                   plane: tuple[float, float, float]) -> np.ndarray:
    """The rows of :func:`generate_scene` for the cars ``poses`` (``(n, 3)`` ``x, z, heading``) on the road plane
    ``(h, s_x, s_z)``: overlapping ones dropped, those in view placed and labelled as ApolloCar3D labels them."""
    h, sx, sz = plane
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
    # Python floats in the loop over the cars: the same doubles as the arrays' elements, the same arithmetic
    for i, (left, right, top, bottom, box) in enumerate(zip(u0.tolist(), u1.tolist(), v0.tolist(), v1.tolist(),
                                                            full.tolist())):
        c0, c1 = max(math.floor(left / scale), 0), min(math.ceil(right / scale), grid_w)
        r0, r1 = max(math.floor(top / scale), 0), min(math.ceil(bottom / scale), grid_h)
        if c1 <= c0 or r1 <= r0 or box <= 0:
            continue
        window = occupied[r0:r1, c0:c1]
        free = window.size - int(np.count_nonzero(window))
        visible[i] = min(free / max(box, window.size), 1.0)
        area[i] = m.box_fill * visible[i] * box * scale * scale
        # the car hides the central part of its box (a silhouette does not fill its box)
        du, dv = shrink * (right - left), shrink * (bottom - top)
        o0, o1 = max(round((left + du) / scale), 0), min(round((right - du) / scale), grid_w)
        q0, q1 = max(round((top + dv) / scale), 0), min(round((bottom - dv) / scale), grid_h)
        occupied[q0:q1, o0:o1] = True
    return visible, area


def _drop_overlapping(poses: np.ndarray, m: SceneModel) -> np.ndarray:
    """Drop cars whose footprint overlaps an earlier one (cross street vs lanes, parked vs lanes).

    Footprints are the axis-aligned boxes (in x, z) of ``car_length[1] x car_width``
    rotated by the heading; greedy in list order.
    """
    clash = footprint_clash(poses[:, 0], poses[:, 1], poses[:, 2], m)
    keep = np.zeros(poses.shape[0], dtype=bool)
    for i in range(poses.shape[0]):
        keep[i] = not bool((clash[i, :i] & keep[:i]).any())
    return poses[keep]


def footprint_clash(x: np.ndarray, z: np.ndarray, heading: np.ndarray, m: SceneModel) -> np.ndarray:
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

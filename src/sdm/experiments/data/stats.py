"""Statistics of annotation sets and Sky configurations, for calibration and reports.

All depths and coordinates are metres (camera frame), screen positions are
screen pixels (rows x cols of the 128 x 256 Sky screen); "Avg. Dist." is in
millimetres like Table 2.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd
import torch

from ...camera import APOLLO_CAMERA_5, Camera
from ...errors import SDMInputError
from ..paper import PAPER_AVG_DIST_MM, PAPER_CARS_PER_IMAGE, PAPER_TARGET_DEPTH  # noqa: F401 (the calibration targets)
from ...sky import SkyConfiguration, circle_offsets, noise_displacement
from .readers import ImageCars



def car_table(images: Sequence[ImageCars], camera: Camera = APOLLO_CAMERA_5) -> pd.DataFrame:
    """One row per labelled car.

    Columns: ``image_id``; ``x, y, z`` (m); ``row, col`` (screen pixels, float;
    NaN for cars behind the camera); ``on_screen`` (bool, the car enters ``E``).
    """
    ids, rows = [], []
    for image in images:
        ids.extend([image.image_id] * image.num_cars)
        rows.append(image.centres.numpy())
    xyz = np.concatenate(rows) if rows else np.zeros((0, 3))
    screen = np.full((xyz.shape[0], 2), np.nan)
    front = xyz[:, 2] > 0
    if front.any():
        screen[front] = camera.project(torch.from_numpy(xyz[front])).numpy()
    height, width = camera.screen_shape
    on_screen = front & (screen[:, 0] >= 0) & (screen[:, 0] < height) & (screen[:, 1] >= 0) & (screen[:, 1] < width)
    return pd.DataFrame(
        {"image_id": ids, "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "row": screen[:, 0], "col": screen[:, 1], "on_screen": on_screen}
    )


def image_table(images: Sequence[ImageCars], camera: Camera = APOLLO_CAMERA_5) -> pd.DataFrame:
    """One row per image: ``image_id``, ``n_cars`` (labelled), ``n_on_screen``."""
    cars = car_table(images, camera)
    on_screen = cars.groupby("image_id", sort=False)["on_screen"].sum()
    ids = [image.image_id for image in images]
    return pd.DataFrame(
        {
            "image_id": ids,
            "n_cars": [image.num_cars for image in images],
            "n_on_screen": [int(on_screen.get(i, 0)) for i in ids],
        }
    )


def require_cars_on_screen(images: Sequence[ImageCars], camera: Camera = APOLLO_CAMERA_5, source: str = "annotations") -> int:
    """Check that an annotation set can give a usable Sky configuration; call it right after reading.

    An image with no car on the screen (none labelled, or all behind the camera
    or off the screen) gives an *empty* configuration, which every stage
    accepts; but when *every* image is like that, the Sky dataset has nothing
    to train or score on, so the workflow should stop at its first stage.

    Args:
        images: the annotation set (from a reader).
        camera: its camera and screen.
        source: what to name in the message (the folder or CSV file read).

    Returns:
        The number of images with at least one car on the screen (> 0).

    Raises:
        SDMInputError: naming ``source``, when there is no image or no image
            has a car on the screen.
    """
    images = list(images)
    if not images:
        raise SDMInputError(f"{source}: no image in the annotations")
    per_image = image_table(images, camera)
    usable = int((per_image["n_on_screen"] > 0).sum())
    if usable == 0:
        height, width = camera.screen_shape
        n_cars = int(per_image["n_cars"].sum())
        raise SDMInputError(
            f"{source}: none of its {len(images)} images has a car on the {height} x {width} screen "
            f"({n_cars} labelled cars in all; a car counts when it is in front of the camera and its centre "
            "projects into the lower half of the image): every Sky configuration would be empty, "
            "so there is nothing to train or score on"
        )
    return usable


def fit_road_plane(images: Sequence[ImageCars]) -> dict[str, float]:
    """Least-squares plane ``y = h + s_x x + s_z z`` through all car centres.

    Returns:
        ``{"h", "s_x", "s_z", "residual_sd"}`` (metres, metres per metre, metres).
    """
    xyz = np.concatenate([image.centres.numpy() for image in images] or [np.zeros((0, 3))])
    if xyz.shape[0] < 3:
        return {"h": math.nan, "s_x": math.nan, "s_z": math.nan, "residual_sd": math.nan}
    design = np.column_stack([np.ones(len(xyz)), xyz[:, 0], xyz[:, 2]])
    coef, *_ = np.linalg.lstsq(design, xyz[:, 1], rcond=None)
    residual = xyz[:, 1] - design @ coef
    return {"h": float(coef[0]), "s_x": float(coef[1]), "s_z": float(coef[2]), "residual_sd": float(residual.std())}


def circle_overlap(configuration: SkyConfiguration, camera: Camera = APOLLO_CAMERA_5) -> dict[str, int]:
    """How the circles of one configuration crowd each other.

    Each active pixel of ``E`` (a car centre on screen) paints a disc of
    radius ``3 ln 4`` clipped to the screen.

    Returns:
        ``{"circles", "overlapping", "painted", "covered", "shared"}``: number of
        circles; circles sharing at least one pixel with another circle;
        on-screen disc pixels summed over circles; distinct pixels covered
        (the active pixels of ``E'``); pixels covered by two circles or more.
    """
    centres = configuration.centres.numpy()
    height, width = camera.screen_shape
    if centres.shape[0] == 0:
        return {"circles": 0, "overlapping": 0, "painted": 0, "covered": 0, "shared": 0}
    offsets = circle_offsets().numpy()
    painted = centres[:, None, :] + offsets[None, :, :]
    inside = (painted[..., 0] >= 0) & (painted[..., 0] < height) & (painted[..., 1] >= 0) & (painted[..., 1] < width)
    cells = np.where(inside, painted[..., 0] * width + painted[..., 1], 0)
    counts = np.bincount(cells[inside], minlength=height * width)
    crowded = (counts[cells] >= 2) & inside
    return {
        "circles": int(centres.shape[0]),
        "overlapping": int(crowded.any(axis=1).sum()),
        "painted": int(inside.sum()),
        "covered": int((counts >= 1).sum()),
        "shared": int((counts >= 2).sum()),
    }


def configuration_table(configurations: Sequence[SkyConfiguration], camera: Camera = APOLLO_CAMERA_5) -> pd.DataFrame:
    """One row per configuration.

    Columns: ``image_id``; ``n_circles`` (active pixels of ``E``);
    ``n_points`` (active pixels of ``E'``); ``depth_sum`` (m, sum of ``E'``);
    ``n_target`` (active pixels of ``L``); and the :func:`circle_overlap` counts
    ``overlapping, painted, shared``.
    """
    records = []
    for cfg in configurations:
        overlap = circle_overlap(cfg, camera)
        records.append(
            {
                "image_id": cfg.image_id,
                "n_circles": overlap["circles"],
                "n_points": cfg.num_points,
                "depth_sum": float(cfg.depth.sum()),
                "n_target": int(cfg.target.sum()),
                "overlapping": overlap["overlapping"],
                "painted": overlap["painted"],
                "shared": overlap["shared"],
            }
        )
    columns = ["image_id", "n_circles", "n_points", "depth_sum", "n_target", "overlapping", "painted", "shared"]
    return pd.DataFrame.from_records(records, columns=columns)


def target_mean_depth(configurations: Sequence[SkyConfiguration]) -> float:
    """Mean depth (m) of the target points: ``E'`` values pooled over all configurations."""
    total = sum(float(cfg.depth.sum()) for cfg in configurations)
    count = sum(cfg.num_points for cfg in configurations)
    return total / count if count else math.nan


def avg_dist_mm(mean_depth: float, noise_levels: Sequence[int] = (1, 2, 3, 4), camera: Camera = APOLLO_CAMERA_5) -> dict[int, float]:
    """Table 2's "Avg. Dist." (mm) per noise level for a target-point mean depth (m)."""
    return {int(n): 1000.0 * noise_displacement(int(n), mean_depth, camera) for n in noise_levels}


def summarize(
    images: Sequence[ImageCars],
    configurations: Sequence[SkyConfiguration],
    camera: Camera = APOLLO_CAMERA_5,
) -> dict[str, float]:
    """The calibration statistics of an annotation set and its Sky configurations.

    Keys (units): ``images``; ``cars_per_image``; ``on_screen_per_image``
    (cars entering ``E``); ``circles_per_configuration`` (active pixels of
    ``E``, after same-pixel merges); ``mean_car_depth`` and
    ``median_car_depth`` (m, over labelled cars in front of the camera);
    ``points_per_configuration``; ``target_mean_depth`` (m);
    ``circle_overlap_rate`` (fraction of circles sharing a pixel with
    another); ``hidden_pixel_fraction`` (fraction of painted disc pixels
    overwritten by a nearer circle); ``avg_dist_<n>_mm`` for n = 1..4;
    ``plane_h``, ``plane_s_x``, ``plane_s_z``, ``plane_residual_sd``.
    """
    images_df = image_table(images, camera)
    cars = car_table(images, camera)
    configs = configuration_table(configurations, camera)
    front = cars[cars["z"] > 0]
    painted = configs["painted"].sum()
    n_circles = configs["n_circles"].sum()
    depth = target_mean_depth(configurations)
    plane = fit_road_plane(images)
    summary = {
        "images": len(images),
        "cars_per_image": float(images_df["n_cars"].mean()) if len(images_df) else math.nan,
        "on_screen_per_image": float(images_df["n_on_screen"].mean()) if len(images_df) else math.nan,
        "circles_per_configuration": float(configs["n_circles"].mean()) if len(configs) else math.nan,
        "mean_car_depth": float(front["z"].mean()) if len(front) else math.nan,
        "median_car_depth": float(front["z"].median()) if len(front) else math.nan,
        "points_per_configuration": float(configs["n_points"].mean()) if len(configs) else math.nan,
        "target_mean_depth": depth,
        "circle_overlap_rate": float(configs["overlapping"].sum() / n_circles) if n_circles else math.nan,
        "hidden_pixel_fraction": float(1 - configs["n_points"].sum() / painted) if painted else math.nan,
    }
    for noise_level, value in avg_dist_mm(depth, camera=camera).items():
        summary[f"avg_dist_{noise_level}_mm"] = value
    summary.update({f"plane_{key}": value for key, value in plane.items()})
    return summary


#: Targets of the synthetic default, by :func:`summarize` key (paper; docs/method/paper.md).
TARGETS = {
    "cars_per_image": PAPER_CARS_PER_IMAGE,
    "target_mean_depth": PAPER_TARGET_DEPTH,
    **{f"avg_dist_{noise_level}_mm": value for noise_level, value in PAPER_AVG_DIST_MM.items()},
}


def comparison_table(summaries: dict[str, dict[str, float]]) -> pd.DataFrame:
    """Side-by-side table of :func:`summarize` outputs.

    Args:
        summaries: ``{name: summary}``, e.g. ``{"synthetic": ..., "real sample": ...}``.

    Returns:
        One row per statistic, one column per name, plus ``target`` (the
        paper's figure where there is one, NaN elsewhere) and, per name,
        ``<name> / target`` (ratio).
    """
    keys = list(dict.fromkeys(key for summary in summaries.values() for key in summary))
    table = pd.DataFrame({name: [summary.get(key, math.nan) for key in keys] for name, summary in summaries.items()}, index=keys)
    table["target"] = [TARGETS.get(key, math.nan) for key in keys]
    for name in summaries:
        table[f"{name} / target"] = table[name] / table["target"]
    return table


def histogram_table(values: dict[str, np.ndarray], bins: np.ndarray) -> pd.DataFrame:
    """Normalised histograms (fraction per bin) of several samples on common ``bins``.

    Returns:
        One row per bin (``low``, ``high``) and one column per name.
    """
    bins = np.asarray(bins, dtype=float)
    table = pd.DataFrame({"low": bins[:-1], "high": bins[1:]})
    for name, sample in values.items():
        counts, _ = np.histogram(np.asarray(sample, dtype=float), bins=bins)
        table[name] = counts / max(len(sample), 1)
    return table

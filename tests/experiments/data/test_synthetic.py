"""The synthetic ApolloCar3D default: layout, determinism, atomicity, realism and calibration."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from sdm.camera import APOLLO_CAMERA_5
from sdm.experiments.data import build_sky_dataset, read_apollo_camera, read_apollo_folder, synthetic_images, write_synthetic_apollo
from sdm.experiments.data import scene as scene_module
from sdm.experiments.data import synthetic as synthetic_module
from sdm.experiments.data.stats import (
    PAPER_AVG_DIST_MM,
    PAPER_CARS_PER_IMAGE,
    avg_dist_mm,
    fit_road_plane,
    summarize,
    target_mean_depth,
)
from sdm.errors import SDMInputError
from sdm.sky import build_configuration

SAMPLE = Path(__file__).resolve().parents[3] / "data" / "apollocar3d-sample"

#: Tolerances of the calibration: Avg. Dist. within 5% of Table 2, cars per image within 10% of 11.4.
AVG_DIST_TOLERANCE = 0.05
CARS_TOLERANCE = 0.10


def files_of(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def small_set(tmp_path_factory) -> Path:
    return write_synthetic_apollo(tmp_path_factory.mktemp("syn") / "apollo", n_images=300, seed=7)


@pytest.fixture(scope="module")
def calibration_set():
    """1,000 images of the default seed, in memory, with their configurations."""
    images = synthetic_images(1000, seed=0)
    configurations = [build_configuration(i.centres, image_id=i.image_id) for i in images]
    return images, configurations


def test_layout_is_apollocar3d(small_set):
    poses = sorted((small_set / "car_poses").glob("*.json"))
    assert len(poses) == 300
    assert poses[0].name == "synthetic_00000_Camera_5.json"
    cars = json.loads(poses[0].read_text())
    assert isinstance(cars, list)
    for c in cars:
        assert set(c) == {"area", "car_id", "pose", "visible_rate"}
        assert len(c["pose"]) == 6 and 0 <= c["car_id"] < 79 and 0.3 <= c["visible_rate"] <= 1.0
    assert read_apollo_camera(small_set) == APOLLO_CAMERA_5
    provenance = json.loads((small_set / "synthetic.json").read_text())
    assert provenance["seed"] == 7 and provenance["n_images"] == 300
    images = read_apollo_folder(small_set)
    assert provenance["n_cars"] == sum(i.num_cars for i in images)


def test_in_memory_images_match_the_files(small_set):
    from_files = read_apollo_folder(small_set)
    in_memory = synthetic_images(300, seed=7)
    assert [i.image_id for i in from_files] == [i.image_id for i in in_memory]
    assert all(torch.equal(a.centres, b.centres) for a, b in zip(from_files, in_memory))


def test_same_seed_same_bytes_other_seed_differs(tmp_path):
    a = files_of(write_synthetic_apollo(tmp_path / "a", n_images=40, seed=3))
    b = files_of(write_synthetic_apollo(tmp_path / "b", n_images=40, seed=3))
    c = files_of(write_synthetic_apollo(tmp_path / "c", n_images=40, seed=4))
    assert a == b
    assert a.keys() == c.keys() and a != c


def test_image_does_not_depend_on_n_images():
    few = synthetic_images(10, seed=0)
    many = synthetic_images(60, seed=0)
    assert all(torch.equal(a.centres, b.centres) for a, b in zip(few, many[:10]))


def test_refuses_to_clobber_and_overwrites_on_request(tmp_path):
    folder = tmp_path / "apollo"
    folder.mkdir()
    (folder / "mine.txt").write_text("keep me")
    with pytest.raises(SDMInputError, match="exists and is not empty"):
        write_synthetic_apollo(folder, n_images=5)
    assert (folder / "mine.txt").read_text() == "keep me"
    write_synthetic_apollo(folder, n_images=5, overwrite=True)
    assert not (folder / "mine.txt").exists() and len(list((folder / "car_poses").glob("*.json"))) == 5
    assert sorted(p.name for p in tmp_path.iterdir()) == ["apollo"]


def test_error_leaves_nothing_half_written(tmp_path, monkeypatch):
    calls = {"n": 0}
    real = scene_module.generate_scene

    def failing(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] > 3:
            raise RuntimeError("disk on fire")
        return real(*args, **kwargs)

    monkeypatch.setattr(scene_module, "generate_scene", failing)
    with pytest.raises(RuntimeError, match="disk on fire"):
        write_synthetic_apollo(tmp_path / "apollo", n_images=10)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("kwargs", [{"n_images": 0}, {"n_images": 2.5}, {"seed": -1}])
def test_bad_arguments(tmp_path, kwargs):
    with pytest.raises(SDMInputError):
        write_synthetic_apollo(tmp_path / "apollo", **kwargs)


# -- realism ------------------------------------------------------------------------------------


def test_cars_do_not_interpenetrate(small_set):
    """Footprints (at least 4.2 m x 1.7 m, oriented by the yaw) of two cars never overlap."""
    for path in sorted((small_set / "car_poses").glob("*.json")):
        poses = np.array([c["pose"] for c in json.loads(path.read_text())]).reshape(-1, 6)
        heading = poses[:, 2] + math.pi  # yaw ~ -pi: driving away from the camera
        c, s = np.abs(np.cos(heading)), np.abs(np.sin(heading))
        half_x = 2.1 * s + 0.85 * c
        half_z = 2.1 * c + 0.85 * s
        x, z = poses[:, 3], poses[:, 5]
        overlap = (np.abs(x[:, None] - x[None, :]) < half_x[:, None] + half_x[None, :]) & (
            np.abs(z[:, None] - z[None, :]) < half_z[:, None] + half_z[None, :]
        )
        np.fill_diagonal(overlap, False)
        assert not overlap.any(), path.name


def test_moving_lanes_keep_five_metre_gaps():
    """Within a lane of moving traffic, bumper-to-bumper gaps are at least ``min_gap`` (5 m)."""
    model = scene_module.SceneModel(p_parked=0.0, p_cross=0.0, curvature_sd=0.0)
    for image in synthetic_images(200, seed=1, model=model):
        xyz = image.centres.numpy()
        same_lane = np.abs(xyz[:, None, 0] - xyz[None, :, 0]) < 1.0
        np.fill_diagonal(same_lane, False)
        dz = np.abs(xyz[:, None, 2] - xyz[None, :, 2])[same_lane]
        assert (dz >= model.car_length[0] + model.min_gap).all(), image.image_id


@pytest.mark.slow
def test_cars_sit_on_the_road_plane_of_the_real_sample(calibration_set):
    images, _ = calibration_set
    plane = fit_road_plane(images)
    assert abs(plane["s_z"] - 0.17) < 0.01 and abs(plane["h"] - 1.12) < 0.15
    if (SAMPLE / "car_poses").is_dir():
        real = fit_road_plane(read_apollo_folder(SAMPLE))
        assert abs(plane["s_z"] - real["s_z"]) < 0.02 and abs(plane["h"] - real["h"]) < 0.2


def test_depth_spread_and_lanes(calibration_set):
    images, _ = calibration_set
    xyz = torch.cat([i.centres for i in images]).numpy()
    z, x = xyz[:, 2], xyz[:, 0]
    assert (z > 3).all() and np.percentile(z, 90) > 90 and z.max() > 120  # depth spread out to 100+ m
    assert (x < -3).mean() > 0.1 and (x > 3).mean() > 0.1  # neighbour lanes and kerbs on both sides
    counts = np.array([i.num_cars for i in images])
    assert counts.max() <= 45 and np.percentile(counts, 10) >= 2  # ApolloCar3D: at most 37 per image


# -- calibration ----------------------------------------------------------------------------------


def test_calibration_on_1000_images(calibration_set):
    images, configurations = calibration_set
    cars = np.mean([i.num_cars for i in images])
    assert abs(cars / PAPER_CARS_PER_IMAGE - 1) <= CARS_TOLERANCE, cars
    measured = avg_dist_mm(target_mean_depth(configurations))
    for level, paper in PAPER_AVG_DIST_MM.items():
        assert abs(measured[level] / paper - 1) <= AVG_DIST_TOLERANCE, (level, measured[level], paper)


@pytest.mark.slow
def test_default_sky_dataset_statistics():
    """The full default: 5,277 images, 4,248 configurations (build time: benchmarks/speed/bench_sdm.py)."""
    images = synthetic_images(5277, seed=0)
    configurations = build_sky_dataset(images, progress=False)
    assert len(configurations) == 4248
    summary = summarize(images, configurations)
    assert abs(summary["cars_per_image"] / PAPER_CARS_PER_IMAGE - 1) <= CARS_TOLERANCE
    for level, paper in PAPER_AVG_DIST_MM.items():
        assert abs(summary[f"avg_dist_{level}_mm"] / paper - 1) <= AVG_DIST_TOLERANCE
    # crowding: circles do overlap, but most pixels of a circle stay visible
    assert 0.3 < summary["circle_overlap_rate"] < 0.8
    assert 0.05 < summary["hidden_pixel_fraction"] < 0.3
    assert math.isfinite(summary["mean_car_depth"])

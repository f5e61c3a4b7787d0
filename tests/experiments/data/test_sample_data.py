"""The real ApolloCar3D sample shipped in the repository (data/apollocar3d-sample) reads as its README says."""
from __future__ import annotations

import json
from pathlib import Path

import torch

from sdm.camera import APOLLO_CAMERA_5, Camera
from sdm.experiments.data import SkyFile, build_sky_dataset, read_annotations, require_cars_on_screen, write_sky_file
from sdm.sky import SKY_SHIFT

SHIPPED = Path(__file__).resolve().parents[3] / "data" / "apollocar3d-sample"


def test_the_shipped_sample_has_its_files_licence_and_attribution():
    poses = sorted((SHIPPED / "car_poses").glob("*.json"))
    assert len(poses) == 57
    assert sorted(p.name for p in SHIPPED.iterdir()) == ["LICENSE", "README.md", "camera", "car_poses", "config.yaml"]
    assert "Apache License" in (SHIPPED / "LICENSE").read_text() and "Version 2.0" in (SHIPPED / "LICENSE").read_text()
    readme = (SHIPPED / "README.md").read_text()
    assert "ApolloScapeAuto/dataset-api" in readme and "Apache" in readme


def test_the_shipped_sample_reads_57_images_and_camera_5():
    images, camera = read_annotations("apollo", SHIPPED)
    assert camera == APOLLO_CAMERA_5 == Camera.from_file(SHIPPED / "camera" / "Camera_5.txt")
    files = sorted((SHIPPED / "car_poses").glob("*.json"))
    assert [image.image_id for image in images] == [p.stem for p in files]
    assert len(images) == 57 and sum(image.num_cars for image in images) == 251
    for image, path in zip(images, files):
        expected = [car["pose"][3:] for car in json.loads(path.read_text())]
        assert torch.equal(image.centres, torch.tensor(expected, dtype=torch.float64).reshape(-1, 3))
    assert require_cars_on_screen(images, camera, source=str(SHIPPED)) == 57


def test_the_shipped_sample_makes_a_sky_file(tmp_path):
    images, camera = read_annotations("apollo", SHIPPED)
    configurations = build_sky_dataset(images, n_sample=57, seed=0, camera=camera, progress=False)
    write_sky_file(tmp_path / "sky.bin", configurations, SKY_SHIFT, camera, {"source": "apollocar3d-sample"})
    sky = SkyFile(tmp_path / "sky.bin")
    assert len(sky) == 57 and all(cfg.num_points > 0 for cfg in sky)

"""Data checks the workflow's first stages rely on: an unusable annotation set stops at once, naming it;
a set with some empty images goes through; the sample size names the config key it came from."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from sdm.batch import ConfigurationSet
from sdm.experiments.data import (
    SkyFile, build_sky_dataset, read_annotations, require_cars_on_screen, sample_indices, synthetic_images,
    write_sky_file,
)
from sdm.errors import SDMInputError
from sdm.metrics import distance
from sdm.sky import SKY_SHIFT
from sdm.train import TrainSettings, train


def write_folder(root: Path, cars_by_name: dict[str, list[list[float]]]) -> Path:
    """An ApolloCar3D folder: car_poses/<name>.json with one car per centre (x, y, z), no camera folder."""
    (root / "car_poses").mkdir(parents=True)
    for name, centres in cars_by_name.items():
        cars = [{"car_id": 1, "pose": [0.1, 0.0, -3.1, *centre]} for centre in centres]
        (root / "car_poses" / f"{name}.json").write_text(json.dumps(cars))
    return root


def test_a_folder_whose_images_have_no_car_on_screen_is_refused_naming_it(tmp_path):
    folder = write_folder(
        tmp_path / "empty_apollo",
        {
            "no_car": [],
            "behind": [[0.0, 1.5, -10.0]],  # behind the camera
            "above": [[0.0, -40.0, 20.0]],  # in the upper half of the image: not on the screen
            "aside": [[300.0, 1.5, 20.0]],  # far right of the image
        },
    )
    images, camera = read_annotations("apollo", folder)
    assert len(images) == 4
    with pytest.raises(SDMInputError, match=rf"^{folder}: none of its 4 images has a car on the 128 x 256 screen "
                                            r"\(3 labelled cars in all"):
        require_cars_on_screen(images, camera, source=str(folder))


def test_no_image_at_all_is_refused_naming_the_source():
    with pytest.raises(SDMInputError, match=r"^train\.csv: no image"):
        require_cars_on_screen([], source="train.csv")


def test_a_folder_with_some_empty_images_goes_through_to_training(tmp_path):
    """Some images without a car: the check passes, the Sky file keeps their empty configurations,
    and training on the set runs and still recovers the shift."""
    real = synthetic_images(60, seed=3)
    cars = {image.image_id: image.centres.tolist() for image in real}
    cars |= {f"zz_empty_{k:02d}": [] for k in range(30)}
    folder = write_folder(tmp_path / "apollo", cars)
    images, camera = read_annotations("apollo", folder)
    usable = require_cars_on_screen(images, camera, source=str(folder))
    assert usable == sum(1 for image in real if image.num_cars) and 0 < usable <= 60

    configurations = build_sky_dataset(images, n_sample=len(images), seed=0, camera=camera, progress=False)
    write_sky_file(tmp_path / "sky.bin", configurations, SKY_SHIFT, camera)
    sky = SkyFile(tmp_path / "sky.bin")
    loaded = list(sky)
    empty = [cfg.image_id for cfg in loaded if cfg.num_points == 0]
    assert {f"zz_empty_{k:02d}" for k in range(30)} <= set(empty)

    train_set = ConfigurationSet.from_configurations(loaded, sky.camera)
    history = train(train_set, TrainSettings(lr=3e-4, n_epoch=1, s=2, seed=0), progress=False)
    assert bool(torch.isfinite(history.theta).all())
    # 90 configurations give 5 SGD steps per level: near the shift, not at the paper's precision
    assert distance(history.final_theta) < 0.05 * distance((0.0, 0.0))


def test_sample_larger_than_the_set_names_the_callers_key():
    with pytest.raises(SDMInputError, match=r"^n_sample = 128 is larger than the number of images \(57\)$"):
        sample_indices(57, 128, 0)
    with pytest.raises(SDMInputError, match=r"^config key 'sky\.n_images' = 128 is larger than the number of images \(57\)$"):
        sample_indices(57, 128, 0, n_sample_name="config key 'sky.n_images'")
    with pytest.raises(SDMInputError, match=r"^config key 'sky\.seed' must be a non-negative integer, got -1$"):
        build_sky_dataset(synthetic_images(3, seed=0), n_sample=2, seed=-1, progress=False,
                          seed_name="config key 'sky.seed'")

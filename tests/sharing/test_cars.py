"""The car each point belongs to, through the data layer: packed sets, car rows, the real sample, and
synthetic images with exactly K visible cars."""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from owner_reference import reference_cars
from scenes import configurations
from sdm.batch import ConfigurationSet
from sdm.camera import APOLLO_CAMERA_5
from sdm.experiments.data import (
    SkyFile, build_configurations, images_with_cars, read_annotations, set_with_cars, synthetic_images, write_sky_file,
)
from sdm.errors import SDMInputError
from sdm.representation import inside
from sdm.sky import SKY_SHIFT, build_configuration, circle_offsets, paint_circles, render_centres

SHIPPED = Path(__file__).resolve().parents[2] / "data" / "apollocar3d-sample"
SCALING_CARS = (1, 2, 4, 8, 16, 32)


def car_at(row: int, col: int, depth: float) -> list[float]:
    return APOLLO_CAMERA_5.backproject(torch.tensor([[row + 0.5, col + 0.5]], dtype=torch.float64),
                                       torch.tensor([depth], dtype=torch.float64))[0].tolist()


def minimum_circles(centre_image: torch.Tensor) -> torch.Tensor:
    """E' as the minimum of the overlapping discs' values, by a scatter-min: the construction's definition."""
    height, width = centre_image.shape
    active = centre_image.nonzero()
    offsets = circle_offsets()
    painted = (active[:, None, :] + offsets[None, :, :]).reshape(-1, 2)
    values = centre_image[active[:, 0], active[:, 1]].repeat_interleave(offsets.shape[0])
    kept = inside(painted, height, width)
    image = torch.full((height * width,), math.inf, dtype=centre_image.dtype)
    image.scatter_reduce_(0, painted[kept, 0] * width + painted[kept, 1], values[kept], reduce="amin")
    image[torch.isinf(image)] = 0
    return image.view(height, width)


# -- the Sky data itself is unchanged -----------------------------------------------------------


def test_painting_with_owners_gives_the_minimum_of_the_circles_bit_for_bit():
    """Recording the owner changes no depth: E' equals the scatter-min of the discs exactly, on crowded scenes."""
    generator = torch.Generator().manual_seed(4)
    for _ in range(8):
        n = int(torch.randint(1, 60, (1,), generator=generator))
        centres = torch.stack((
            (torch.rand(n, generator=generator, dtype=torch.float64) - 0.5) * 40,
            1 + torch.rand(n, generator=generator, dtype=torch.float64) * 8,
            5 + torch.rand(n, generator=generator, dtype=torch.float64).mul(100).round(),  # many equal depths
        ), dim=1)
        image = render_centres(centres).to(torch.float64)
        circles, owner = paint_circles(image)
        assert torch.equal(circles, minimum_circles(image))
        assert torch.equal(owner >= 0, circles > 0)


# -- the packed set -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def crowded():
    return configurations(12, seed=21, mean_cars=20)


def test_a_packed_set_carries_the_car_of_each_point(crowded):
    data = ConfigurationSet.from_configurations(crowded)
    assert data.cars.dtype == torch.int64 and data.cars.shape == (data.points.shape[0],)
    assert torch.equal(data.cars, torch.cat([cfg.cars for cfg in crowded]))
    order = [7, 2, 2, 11]
    sub = data.subset(order)
    assert torch.equal(sub.cars, torch.cat([crowded[i].cars for i in order]))
    assert data.with_targets(data.targets.clone()).cars is data.cars
    moved = data.to("meta")
    assert moved.cars.device.type == "meta" and moved.cars.shape == data.cars.shape
    assert data.to("cpu") is data


def test_car_rows_number_every_car_that_owns_points_configuration_by_configuration(crowded):
    hidden = build_configuration(torch.tensor([car_at(1, 1, 20.0), car_at(0, 0, 50.0)], dtype=torch.float64))
    empty = build_configuration(torch.zeros(0, 3, dtype=torch.float64))
    configs = [crowded[0], hidden, empty, *crowded[1:4]]
    data = ConfigurationSet.from_configurations(configs)
    point_row, row_car = data.car_rows()
    assert point_row.dtype == row_car.dtype == torch.int64
    assert point_row.shape == (data.points.shape[0],) and row_car.shape[1] == 2
    # the rows, built by hand: every (configuration, car) that owns a point, in order
    expected = sorted({(i, car) for i, cfg in enumerate(configs) for car in cfg.cars.tolist()})
    expected = [list(row) for row in expected]
    assert row_car.tolist() == expected
    assert [1, 0] not in expected and [1, 1] in expected  # the hidden car gets no row, the other one does
    assert not any(i == 2 for i, _ in expected)  # nor the empty configuration
    # each point's row is its own (configuration, car)
    configs_of_points = torch.repeat_interleave(torch.arange(len(configs)), data.counts)
    assert torch.equal(row_car[point_row], torch.stack((configs_of_points, data.cars), dim=1))
    assert torch.equal(data.point_configs(), configs_of_points)
    # a subset numbers its own rows
    sub_rows, sub_table = data.subset([3, 0]).car_rows()
    assert sub_table[:, 0].unique().tolist() == [0, 1] and int(sub_rows.max()) + 1 == sub_table.shape[0]


def test_a_set_without_car_index_says_so(crowded):
    data = ConfigurationSet.from_configurations(crowded[:3])
    bare = ConfigurationSet(data.points, data.pixels, data.offsets, data.targets, data.camera)
    assert bare.cars is None and bare.subset([1]).cars is None and bare.with_targets(bare.targets).cars is None
    with pytest.raises(SDMInputError, match=r"this set has no car index"):
        bare.car_rows()
    with pytest.raises(SDMInputError, match=r"cars must be a \(\d+,\) int64 tensor"):
        ConfigurationSet(data.points, data.pixels, data.offsets, data.targets, data.camera, cars=data.cars[:-1])
    with pytest.raises(SDMInputError, match=r"cars must be a \(\d+,\) int64 tensor"):
        ConfigurationSet(data.points, data.pixels, data.offsets, data.targets, data.camera, cars=data.cars.int())


def test_a_sky_file_gives_back_the_same_car_rows(tmp_path):
    configs = build_configurations(synthetic_images(24, seed=3), progress=False)
    path = tmp_path / "sky.bin"
    write_sky_file(path, configs, SKY_SHIFT, APOLLO_CAMERA_5)
    read = ConfigurationSet.from_configurations(SkyFile(path).load_all())
    built = ConfigurationSet.from_configurations(configs)
    assert torch.equal(read.cars, built.cars)
    assert all(torch.equal(a, b) for a, b in zip(read.car_rows(), built.car_rows()))


def test_the_real_sample_gives_each_point_the_car_of_the_reference():
    """The shipped ApolloCar3D sample: every point's car is the reference loop's, and its circles do overlap."""
    images, camera = read_annotations("apollo", SHIPPED)
    configs = build_configurations(images, SKY_SHIFT, camera, progress=False)
    for cfg in configs:
        assert cfg.cars.tolist() == reference_cars(cfg.pixels, cfg.centres, cfg.centre_depth), cfg.image_id
        assert torch.equal(cfg.depth, cfg.centre_depth[cfg.cars])
    counts = [torch.bincount(cfg.cars, minlength=cfg.centres.shape[0]) for cfg in configs if cfg.num_points]
    assert sum(int((c < 57).sum()) for c in counts) > 20  # many cars lose pixels to nearer ones: the rule matters
    data = ConfigurationSet.from_configurations(configs, camera)
    assert data.car_rows()[1].shape[0] == sum(int((c > 0).sum()) for c in counts)


# -- synthetic images with exactly K visible cars ---------------------------------------------------


@pytest.mark.parametrize("n_cars", SCALING_CARS)
def test_images_with_cars_have_exactly_that_many_cars_each_owning_points(n_cars):
    data = set_with_cars(8, n_cars, seed=1)
    assert len(data) == 8
    point_row, row_car = data.car_rows()
    assert row_car.shape == (8 * n_cars, 2)
    assert row_car.tolist() == [[i, car] for i in range(8) for car in range(n_cars)]
    images = images_with_cars(8, n_cars, seed=1)
    assert all(image.centres.shape == (n_cars, 3) for image in images)
    assert all(bool((image.centres[:, 2] > 0).all()) for image in images)
    assert [image.image_id for image in images] == [f"cars{n_cars:02d}_{i:05d}" for i in range(8)]


def test_images_with_cars_sit_where_the_default_model_puts_cars():
    """Their depths and screen rows follow the default model's labelled cars (same road, same camera)."""
    def depths_and_rows(images):
        xyz = torch.cat([image.centres for image in images])
        return xyz[:, 2].numpy(), APOLLO_CAMERA_5.project(xyz)[:, 0].numpy()

    default = [image for image in synthetic_images(200, seed=2) if image.num_cars]
    z_default, _ = depths_and_rows(default)
    z_one, rows_one = depths_and_rows(images_with_cars(200, 1, seed=2))
    z_many, rows_many = depths_and_rows(images_with_cars(12, 16, seed=2))
    for z in (z_one, z_many):
        assert z.min() > 1.0 and z.max() < 250.0
        assert 0.6 < np.median(z) / np.median(z_default) < 1.6
    assert rows_one.min() >= 0 and rows_many.max() < APOLLO_CAMERA_5.screen_height


def test_images_with_cars_are_deterministic_per_image():
    a = images_with_cars(6, 8, seed=4)
    b = images_with_cars(6, 8, seed=4)
    longer = images_with_cars(9, 8, seed=4)
    other = images_with_cars(6, 8, seed=5)
    assert all(torch.equal(x.centres, y.centres) for x, y in zip(a, b))
    assert all(torch.equal(x.centres, y.centres) for x, y in zip(a, longer))  # image i does not depend on n_images
    assert not any(torch.equal(x.centres, y.centres) for x, y in zip(a, other))
    first, again = set_with_cars(4, 8, seed=4), set_with_cars(4, 8, seed=4)
    assert torch.equal(first.points, again.points) and torch.equal(first.cars, again.cars)
    assert torch.equal(first.targets, again.targets)


@pytest.mark.parametrize("bad", [0, -2, 2.5, True, "4", None])
def test_a_bad_number_of_cars_is_refused_naming_the_key(bad):
    key = "config key 'research.objects.scaling.cars[1]'"
    with pytest.raises(SDMInputError, match=rf"^{re.escape(key)} must be a positive integer, got "):
        images_with_cars(2, bad, n_cars_name=key)
    with pytest.raises(SDMInputError, match=r"^n_cars must be a positive integer"):
        set_with_cars(2, bad)


def test_bad_image_counts_and_seeds_are_refused_naming_them():
    with pytest.raises(SDMInputError, match=r"^n_images must be a positive integer, got 0"):
        images_with_cars(0, 4)
    with pytest.raises(SDMInputError, match=r"^scaling\.seed must be a non-negative integer, got -1"):
        images_with_cars(2, 4, seed=-1, seed_name="scaling.seed")


def test_more_cars_than_a_screen_holds_are_refused_naming_the_argument():
    with pytest.raises(SDMInputError, match=r"^n_cars = 3000: image 0 could not hold 3000 visible cars on the 128x256"):
        images_with_cars(1, 3000)

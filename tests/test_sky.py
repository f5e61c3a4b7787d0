import math

import pytest
import torch

from owner_reference import reference_cars
from scenes import configurations, road_centres
from sdm.camera import APOLLO_CAMERA_5
from sdm.errors import SDMInputError
from sdm.representation import occupancy, screen_pixels
from sdm.sky import (
    CIRCLE_RADIUS, SKY_SHIFT, add_target_noise, build_configuration, circle_offsets, noise_displacement,
)


def test_circle_is_the_57_pixel_disc_of_the_appendix():
    offsets = circle_offsets()
    assert len(offsets) == 57
    d = offsets.double().norm(dim=1)
    assert bool((torch.exp(-d / 3) >= 0.25).all())
    ring = [(i, j) for i in range(-6, 7) for j in range(-6, 7) if math.exp(-math.hypot(i, j) / 3) >= 0.25]
    assert sorted(map(tuple, offsets.tolist())) == sorted(ring)


def test_configuration_from_one_car():
    cfg = build_configuration(torch.tensor([[1.0, 3.0, 30.0]], dtype=torch.float64))
    assert cfg.num_points == 57 and bool((cfg.depth == 30.0).all())
    # Each point of Q lies in its own pixel.
    pixels, _ = screen_pixels(APOLLO_CAMERA_5.project(cfg.points()), APOLLO_CAMERA_5)
    assert torch.equal(pixels, cfg.pixels)
    # L is the occupancy of the shifted points, here a shifted copy of the disc.
    moved = cfg.points() + torch.tensor([*SKY_SHIFT, 0.0], dtype=torch.float64)
    expected = occupancy(torch.floor(APOLLO_CAMERA_5.project(moved)).long(), APOLLO_CAMERA_5.screen_shape)
    assert torch.equal(cfg.target, expected) and int(cfg.target.sum()) == 57


def test_overlapping_circles_keep_the_nearest_depth():
    centres = torch.tensor([[0.0, 3.0, 30.0], [0.4, 6.1, 60.0]], dtype=torch.float64)  # 1-2 px apart
    cfg = build_configuration(centres)
    circles = cfg.circles()
    near_pixel = tuple(cfg.centres[cfg.centre_depth == 30.0][0].tolist())
    assert circles[near_pixel] == 30.0
    assert set(cfg.depth.unique().tolist()) <= {30.0, 60.0}
    assert cfg.num_points < 2 * 57  # they overlap


def test_cars_behind_the_camera_or_off_screen_are_dropped_and_empty_images_are_empty():
    cfg = build_configuration(torch.tensor([[0.0, 1.0, -5.0], [500.0, 1.0, 10.0], [0.0, -30.0, 10.0]]))
    assert cfg.num_points == 0 and not bool(cfg.target.any())
    assert build_configuration(torch.zeros(0, 3)).num_points == 0


@pytest.mark.parametrize("shift", [(math.nan, 0.3), (0.5, math.inf), (0.5,)])
def test_bad_shift(shift):
    with pytest.raises(SDMInputError, match="shift"):
        build_configuration(torch.tensor([[1.0, 3.0, 30.0]]), shift)


def test_bad_centres():
    with pytest.raises(SDMInputError, match="shape \\(M, 3\\)"):
        build_configuration(torch.zeros(4, 2))
    with pytest.raises(SDMInputError, match="finite"):
        build_configuration(torch.tensor([[math.nan, 1.0, 10.0]]))


def test_target_noise_moves_every_pixel_within_the_level():
    cfg = configurations(1, seed=3)[0]
    for level in range(5):
        noisy = add_target_noise(cfg.target, level, torch.Generator().manual_seed(level))
        again = add_target_noise(cfg.target, level, torch.Generator().manual_seed(level))
        assert torch.equal(noisy, again)
        # every noisy pixel is within `level` (Chebyshev) of some original active pixel
        reach = torch.nn.functional.max_pool2d(cfg.target.float()[None, None], 2 * level + 1, 1, level)[0, 0] > 0
        assert bool((noisy <= reach).all())
        assert int(noisy.sum()) <= int(cfg.target.sum())
    assert torch.equal(add_target_noise(cfg.target, 0), cfg.target)
    assert not torch.equal(add_target_noise(cfg.target, 2, torch.Generator().manual_seed(0)), cfg.target)
    with pytest.raises(SDMInputError, match="noise level"):
        add_target_noise(cfg.target, -1)


@pytest.mark.parametrize("level, paper_mm", [(1, 283.4), (2, 494.6), (3, 699.8), (4, 904.8)])
def test_avg_dist_formula_reproduces_table_2_with_the_apollo_mean_depth(level, paper_mm):
    assert noise_displacement(level, 50.95) * 1000 == pytest.approx(paper_mm, rel=1e-3)
    assert noise_displacement(0, 50.95) == 0


def test_radius_constant():
    assert CIRCLE_RADIUS == pytest.approx(4.1589, abs=1e-4)


def test_road_scene_helper_is_seeded():
    a = road_centres(torch.Generator().manual_seed(5), 4)
    b = road_centres(torch.Generator().manual_seed(5), 4)
    assert torch.equal(a, b)


def test_noise_on_a_stack_of_targets_equals_noise_target_by_target():
    """add_target_noise draws one randint for a stack: the same moves as one call per target in turn."""
    from sdm.sky import add_target_noise

    targets = torch.rand(5, 128, 256, generator=torch.Generator().manual_seed(0)) > 0.99
    targets[2] = False  # an empty target draws nothing
    for level in (1, 3):
        loop_generator = torch.Generator().manual_seed(11)
        one_by_one = torch.stack([add_target_noise(target, level, loop_generator) for target in targets])
        together = add_target_noise(targets, level, torch.Generator().manual_seed(11))
        assert torch.equal(together, one_by_one)
        assert not torch.equal(together, targets)


@pytest.mark.parametrize("compiled", [True, False])
def test_draws_into_a_reused_noise_buffer_equal_fresh_draws(compiled):
    """A NoiseBuffer clears only its last draw's pixels (in C where the kernel serves, else in torch): every draw
    into it, after draws of other levels, sizes and a copy, equals the fresh draw of the same seed."""
    from contextlib import nullcontext

    from sdm.mapping import native
    from sdm.sky import NoiseBuffer

    targets = torch.rand(6, 64, 32, generator=torch.Generator().manual_seed(2)) > 0.9
    sparse = targets & (torch.rand(6, 64, 32, generator=torch.Generator().manual_seed(3)) > 0.5)
    buffer = NoiseBuffer(targets)
    with nullcontext() if compiled else native.disabled():
        for target, level, seed in ((targets, 1, 0), (sparse, 4, 1), (targets, 3, 2), (sparse, 0, 3),
                                    (sparse, 2, 4), (targets, 2, 5)):
            fresh = add_target_noise(target, level, torch.Generator().manual_seed(seed))
            reused = add_target_noise(target, level, torch.Generator().manual_seed(seed), out=buffer)
            assert reused is buffer.targets
            assert torch.equal(reused, fresh), (level, seed)
    with pytest.raises(SDMInputError, match="NoiseBuffer of shape"):
        add_target_noise(targets[:2], 1, out=buffer)


# -- the car each point belongs to ---------------------------------------------------------


def car_at(row: int, col: int, depth: float) -> list[float]:
    """A car centre whose centre pixel of ``E`` is ``(row, col)`` at ``depth`` metres."""
    return APOLLO_CAMERA_5.backproject(torch.tensor([[row + 0.5, col + 0.5]], dtype=torch.float64),
                                       torch.tensor([depth], dtype=torch.float64))[0].tolist()


def owned(cfg) -> list[int]:
    """Number of points each car of ``cfg`` owns, in the order of ``cfg.centres``."""
    return torch.bincount(cfg.cars, minlength=cfg.centres.shape[0]).tolist()


def test_every_point_belongs_to_the_nearest_car_whose_circle_covers_it():
    """On crowded road scenes the product's car of each point equals the reference loop's."""
    for cfg in configurations(6, seed=11, mean_cars=20):
        assert cfg.cars.dtype == torch.int64 and cfg.cars.shape == (cfg.num_points,)
        assert cfg.cars.tolist() == reference_cars(cfg.pixels, cfg.centres, cfg.centre_depth)
        assert torch.equal(cfg.depth, cfg.centre_depth[cfg.cars])  # the point's depth is its car's


def test_overlapping_circles_give_the_shared_pixels_to_the_nearer_car():
    near, far = (60, 100, 20.0), (60, 103, 40.0)  # 3 pixels apart: most of the far disc is hidden
    for order in ((near, far), (far, near)):  # whichever is listed first in the annotation
        cfg = build_configuration(torch.tensor([car_at(*c) for c in order], dtype=torch.float64))
        assert cfg.centres.tolist() == [[60, 100], [60, 103]] and cfg.centre_depth.tolist() == [20.0, 40.0]
        assert owned(cfg) == [57, cfg.num_points - 57] and 0 < owned(cfg)[1] < 57
        near_disc = (cfg.pixels - torch.tensor([60, 100])).double().norm(dim=1) <= CIRCLE_RADIUS
        assert bool((cfg.cars[near_disc] == 0).all()) and bool((cfg.cars[~near_disc] == 1).all())
        assert cfg.cars.tolist() == reference_cars(cfg.pixels, cfg.centres, cfg.centre_depth)


def test_equal_depth_circles_give_the_shared_pixels_to_the_car_listed_first():
    """Two cars at the same depth: a pixel both discs cover belongs to the first in row-major order of ``E``."""
    for upper, lower in (((50, 120), (53, 121)), ((50, 121), (53, 120))):
        cfg = build_configuration(torch.tensor([car_at(*lower, 30.0), car_at(*upper, 30.0)], dtype=torch.float64))
        assert cfg.centres.tolist() == [list(upper), list(lower)]
        assert owned(cfg)[0] == 57 and 0 < owned(cfg)[1] < 57
        assert cfg.cars.tolist() == reference_cars(cfg.pixels, cfg.centres, cfg.centre_depth)
    # side by side on one row: the left one is listed first
    cfg = build_configuration(torch.tensor([car_at(70, 42, 25.0), car_at(70, 40, 25.0)], dtype=torch.float64))
    assert cfg.centres.tolist() == [[70, 40], [70, 42]] and owned(cfg)[0] == 57


def test_a_fully_hidden_car_owns_no_point():
    """A far car in the screen's corner, its on-screen quarter disc covered by a nearer car's disc."""
    cfg = build_configuration(torch.tensor([car_at(1, 1, 20.0), car_at(0, 0, 50.0)], dtype=torch.float64))
    assert cfg.centres.tolist() == [[0, 0], [1, 1]] and cfg.centre_depth.tolist() == [50.0, 20.0]
    assert owned(cfg) == [0, cfg.num_points]
    assert set(cfg.depth.tolist()) == {20.0}
    # surrounded by nearer cars: a far car in the middle of the screen, hidden too
    ring = [car_at(64 + dr, 128 + dc, 10.0 + i) for i, (dr, dc) in enumerate(((-3, 0), (3, 0), (0, -3), (0, 3)))]
    cfg = build_configuration(torch.tensor([car_at(64, 128, 80.0), *ring], dtype=torch.float64))
    hidden = cfg.centres.tolist().index([64, 128])
    assert owned(cfg)[hidden] == 0 and all(n > 0 for k, n in enumerate(owned(cfg)) if k != hidden)
    assert cfg.cars.tolist() == reference_cars(cfg.pixels, cfg.centres, cfg.centre_depth)


def test_an_empty_configuration_has_no_car_index():
    cfg = build_configuration(torch.zeros(0, 3, dtype=torch.float64))
    assert cfg.cars.shape == (0,) and cfg.cars.dtype == torch.int64

"""The exact-match set of a unit's shifts (sdm.experiments.identifiability) on scenes where it is known analytically."""
from __future__ import annotations

import math

import pytest
import torch

from sdm import sharing as S
from sdm.batch import ConfigurationSet
from sdm.camera import APOLLO_CAMERA_5
from sdm.errors import SDMInputError
from sdm.experiments.identifiability import exact_sets, scan_offsets
from sdm.sky import CIRCLE_RADIUS, SKY_SHIFT, build_configuration, circle_offsets, rescaled_configuration, scaled_camera

from sharing_scenes import car_grid_scene

STEP = 0.00231  # no grid point lands on a cell's edge


def mean_distance_from_centre(half_a: float, half_b: float) -> float:
    """Mean distance of a uniform point of ``[-A, A] x [-B, B]`` from its centre (closed form)."""
    d = math.hypot(half_a, half_b)
    return (d + half_a**2 / (2 * half_b) * math.log((half_b + d) / half_a)
            + half_b**2 / (2 * half_a) * math.log((half_a + d) / half_b)) / 3


def scene(offset_px):
    """Three separate cars; theta* per car ``offset_px`` screen pixels (col, row) from its points' build shift."""
    data, cars, n_cars = car_grid_scene(3, seed=5, near=15.0, far=45.0)
    sharing = S.sharing("car", data, cars, n_cars)
    units = S.units(data, sharing.param_index, sharing.n_rows)
    depth = torch.stack([data.points[units.point_unit == u, 2][0] for u in range(len(units))])
    dy, dx = data.camera.metres_per_screen_pixel(depth)
    theta = torch.stack((offset_px[0] * dx, offset_px[1] * dy), 1)
    targets = S.render_targets(data, theta, sharing.param_index)
    return data.with_targets(targets), units, S.unit_totals(theta, units), dx.tolist(), dy.tolist()


def test_a_cars_set_is_its_pixel_cell():
    data, units, truth, dx, dy = scene((0.0, 0.0))
    sets = exact_sets(data, units, truth, reach=0.15, step=STEP)
    assert not sets.clipped.any()
    for u in range(len(units)):
        # shifts keeping every point in its pixel: [-dx/2, dx/2) x [-dy/2, dy/2)
        assert float(sets.low[u, 0]) == pytest.approx(-dx[u] / 2, abs=STEP)
        assert float(sets.high[u, 0]) == pytest.approx(dx[u] / 2, abs=STEP)
        assert float(sets.low[u, 1]) == pytest.approx(-dy[u] / 2, abs=STEP)
        assert float(sets.high[u, 1]) == pytest.approx(dy[u] / 2, abs=STEP)
        assert sets.extent[u].tolist() == pytest.approx([dx[u], dy[u]], abs=STEP)
        assert float(sets.distance[u]) == pytest.approx(mean_distance_from_centre(dx[u] / 2, dy[u] / 2), rel=0.03)


def test_theta_star_off_the_cell_centre_moves_the_set_not_its_size():
    data, units, truth, dx, dy = scene((0.3, -0.2))
    sets = exact_sets(data, units, truth, scan=[1], reach=0.15, step=STEP)
    dx, dy = float(dx[1]), float(dy[1])
    assert sets.low[0].tolist() == pytest.approx([-0.8 * dx, -0.3 * dy], abs=STEP)
    assert sets.high[0].tolist() == pytest.approx([0.2 * dx, 0.7 * dy], abs=STEP)
    assert sets.extent[0].tolist() == pytest.approx([dx, dy], abs=STEP)
    centred = mean_distance_from_centre(dx / 2, dy / 2)
    assert float(sets.distance[0]) > 1.05 * centred  # theta* off the centre: the set's points lie farther


def test_a_narrow_scan_is_clipped_and_bad_input_named():
    data, units, truth, dx, dy = scene((0.0, 0.0))
    narrow = exact_sets(data, units, truth, scan=[0], reach=0.25 * float(dx[0]), step=STEP)
    assert bool(narrow.clipped[0])
    noisy = data.with_targets(torch.roll(data.targets, 1, dims=2))
    with pytest.raises(SDMInputError, match="truth: configuration 0"):
        exact_sets(noisy, units, truth, scan=[0])
    with pytest.raises(SDMInputError, match="scan must name units"):
        exact_sets(data, units, truth, scan=[len(units)])
    with pytest.raises(SDMInputError, match="truth must be"):
        exact_sets(data, units, truth[:1])
    with pytest.raises(SDMInputError, match="reach and step"):
        scan_offsets(0.0, 0.01)



@pytest.mark.parametrize("disc", ["pixels", "metres"])
def test_a_finer_screen_shrinks_the_cell_with_its_pixels(disc):
    camera = APOLLO_CAMERA_5
    centres = camera.backproject(torch.tensor([[40.5, 60.5], [70.5, 180.5]], dtype=torch.float64),
                                 torch.tensor([18.0, 33.0], dtype=torch.float64))
    config = build_configuration(centres, SKY_SHIFT, camera)
    assert rescaled_configuration(config, camera, 1, disc) is config
    fine = rescaled_configuration(config, camera, 2, disc)
    scaled = scaled_camera(camera, 2)
    assert scaled.screen_shape == (256, 512) and fine.target.shape == (256, 512)
    assert torch.equal(fine.centres, 2 * config.centres + 1) and torch.equal(fine.centre_depth, config.centre_depth)
    assert fine.num_points == (config.num_points if disc == "pixels" else len(circle_offsets(2 * CIRCLE_RADIUS)) * 2)
    extents = []
    for built, cam in ((config, camera), (fine, scaled)):
        data = ConfigurationSet.from_configurations([built], cam)
        sharing = S.sharing("car", data)
        units = S.units(data, sharing.param_index, sharing.n_rows)
        theta = torch.zeros(sharing.n_rows, 2, dtype=torch.float64)
        data = data.with_targets(S.render_targets(data, theta, sharing.param_index))
        extents.append(exact_sets(data, units, S.unit_totals(theta, units), reach=0.15, step=STEP).extent)
    assert extents[1].reshape(-1).tolist() == pytest.approx((extents[0] / 2).reshape(-1).tolist(), abs=STEP)
    with pytest.raises(SDMInputError, match="disc must be one of"):
        rescaled_configuration(config, camera, 2, "points")
    with pytest.raises(SDMInputError, match="screen scale must be a positive integer"):
        scaled_camera(camera, 0)


def test_the_windowed_scan_is_the_whole_screens_rendering_among_overlapping_cars():
    from sharing_scenes import road_set

    data, cars, n_cars = road_set(2, seed=3, mean_cars=9)
    sharing = S.sharing("car", data, cars, n_cars)
    units = S.units(data, sharing.param_index, sharing.n_rows)
    theta = S.draw_truth(sharing, 11)
    clean = data.with_targets(S.render_targets(data, theta, sharing.param_index))
    truth = S.unit_totals(theta, units)
    step, reach = 0.07, 0.35
    sets = exact_sets(clean, units, truth, scan=range(len(units)), reach=reach, step=step)
    grid = scan_offsets(reach, step)
    for u in range(len(units)):
        brute = []
        for offset in grid:
            moved = theta.clone()
            moved[int(units.rows[u, 0])] += offset
            brute.append(torch.equal(S.render_targets(data, moved, sharing.param_index), clean.targets))
        brute = grid[torch.tensor(brute)]
        assert int(sets.points[u]) == brute.shape[0]
        assert float(sets.distance[u]) == pytest.approx(float(brute.norm(dim=1).mean()))

"""sdm.sharing: the parameter index per point, its levels, theta* draws, targets, units and distances."""
from __future__ import annotations

import copy
import math

import pytest
import torch

from sdm import sharing as S
from sdm.batch import ConfigurationSet
from sdm.errors import SDMInputError
from sdm.sky import SKY_SHIFT, build_configuration, shifted_target

from sharing_scenes import cars_of, road_set, set_with_cars


@pytest.fixture(scope="module")
def road():
    return road_set(6, seed=4)


def test_check_param_index_accepts_and_widens(road):
    data, _, _ = road
    n = data.points.shape[0]
    index = S.check_param_index(torch.zeros(n, dtype=torch.int32), data, 1)
    assert index.shape == (n, 1) and index.dtype == torch.int64
    two = torch.stack((torch.zeros(n, dtype=torch.int64), torch.ones(n, dtype=torch.int64)), 1)
    assert torch.equal(S.check_param_index(two, n, 2), two)


@pytest.mark.parametrize("index, words", [
    (lambda n: torch.zeros(n), "integers"),
    (lambda n: torch.zeros(n, dtype=torch.bool), "integers"),
    (lambda n: torch.zeros(n + 1, dtype=torch.int64), "length"),
    (lambda n: torch.zeros(n, 1, 1, dtype=torch.int64), "shape"),
    (lambda n: torch.zeros(n, 0, dtype=torch.int64), "at least one row"),
    (lambda n: torch.full((n,), -1, dtype=torch.int64), "negative"),
    (lambda n: torch.full((n,), 3, dtype=torch.int64), "[0, 2)"),
    (lambda n: "rows", "integer tensor"),
])
def test_check_param_index_refuses(road, index, words):
    data, _, _ = road
    with pytest.raises(SDMInputError, match="param_index") as error:
        S.check_param_index(index(data.points.shape[0]), data, 2)
    assert words in str(error.value)


def test_a_row_without_points_is_named(road):
    data, _, _ = road
    index = torch.zeros(data.points.shape[0], dtype=torch.int64)
    index[5:] = 2  # row 1 moves nothing
    with pytest.raises(SDMInputError, match="row 1 of theta moves no point"):
        S.check_param_index(index, data, 3)


def test_check_theta(road):
    assert S.check_theta([[0.1, 0.2]], 1).dtype == torch.float64
    for bad, words in [(torch.zeros(3, 2), "3 rows"), (torch.zeros(2, 3), "shape"),
                       (torch.tensor([[math.nan, 0.0], [0.0, 0.0]]), "finite"), ("x", "theta")]:
        with pytest.raises(SDMInputError, match="theta") as error:
            S.check_theta(bad, 2)
        assert words in str(error.value)


def test_point_shifts_sum_rows_and_runs():
    theta = torch.tensor([[1.0, 2.0], [10.0, 20.0], [100.0, 200.0]], dtype=torch.float64)
    index = torch.tensor([[0, 1], [2, 2], [1, 0]])
    assert torch.equal(S.point_shifts(theta, index), torch.tensor([[11.0, 22.0], [200.0, 400.0], [11.0, 22.0]],
                                                                  dtype=torch.float64))
    runs_theta = torch.stack((theta, -theta))
    shifts = S.point_shifts(runs_theta, index[:, :1], runs=torch.tensor([1, 0, 1]))
    assert torch.equal(shifts, torch.stack((-theta[0], theta[2], -theta[1])))


def test_levels_rows_and_tables(road):
    data, cars, n_cars = road
    configs = torch.repeat_interleave(torch.arange(len(data)), data.counts)
    shared = S.shared(data)
    assert shared.n_rows == 1 and int(shared.param_index.abs().sum()) == 0
    per_config = S.per_configuration(data)
    assert torch.equal(per_config.rows[per_config.param_index, 0], configs)
    per_car = S.per_car(data, cars, n_cars)
    assert torch.equal(per_car.rows[per_car.param_index], torch.stack((configs, cars), 1))
    assert per_car.n_rows == len({(int(c), int(k)) for c, k in zip(configs, cars)})
    both = S.camera_and_car(data, cars, n_cars)
    assert both.param_index.shape == (data.points.shape[0], 2)
    assert torch.equal(both.param_index[:, 0], per_config.param_index)
    assert torch.equal(both.param_index[:, 1] - per_config.n_rows, per_car.param_index)
    for level in S.SHARINGS:  # every row of every level has points
        built = S.sharing(level, data, cars, n_cars)
        S.check_param_index(built.param_index, data, built.n_rows)


def test_empty_configuration_gets_no_row():
    configs = [build_configuration(torch.tensor([[0.0, 2.0, 20.0]], dtype=torch.float64)),
               build_configuration(torch.zeros(0, 3, dtype=torch.float64)),
               build_configuration(torch.tensor([[1.0, 2.5, 30.0]], dtype=torch.float64))]
    data, cars, n_cars = set_with_cars(configs)
    level = S.per_configuration(data)
    assert level.rows[:, 0].tolist() == [0, 2]
    assert S.camera_and_car(data, cars, n_cars).n_rows == 4


def test_hidden_car_owns_no_row():
    """A far car whose disc lies under four nearer discs around it: no point, no row, listed hidden."""
    from sdm.camera import APOLLO_CAMERA_5 as camera

    pixels = torch.tensor([[60, 128], [58, 126], [58, 130], [62, 126], [62, 130], [60, 200]], dtype=torch.float64)
    depth = torch.tensor([40.0, 15.0, 15.0, 15.0, 15.0, 20.0], dtype=torch.float64)
    configuration = build_configuration(camera.backproject(pixels + 0.5, depth))
    data, cars, n_cars = set_with_cars([configuration])
    assert n_cars.tolist() == [6]
    level = S.per_car(data, cars, n_cars)
    far = int((configuration.centre_depth == 40.0).nonzero())
    assert level.n_rows == 5 and level.hidden.tolist() == [[0, far]]
    assert S.per_car(data, cars).hidden.shape == (0, 2)  # without n_cars nothing is known about hidden cars
    summary = S.summarise_distances(torch.tensor([0.1, 0.3]), hidden_without_row=len(level.hidden))
    assert (summary.counted, summary.hidden) == (2, 1)


def test_cars_checked(road):
    data, cars, n_cars = road
    with pytest.raises(SDMInputError, match="cars"):
        S.per_car(data, cars[:-1])
    with pytest.raises(SDMInputError, match="cars"):
        S.per_car(data, cars.double())
    with pytest.raises(SDMInputError, match="cars"):
        S.per_car(data, cars, torch.zeros_like(n_cars))
    bare = copy.copy(data)
    bare.cars = None  # a set packed without its points' cars
    with pytest.raises(SDMInputError, match="cars"):
        S.sharing("car", bare)
    with pytest.raises(SDMInputError, match="sharing must be one of"):
        S.sharing("camera", data)


def test_truth_draws_are_seeded_and_sized(road):
    data, cars, n_cars = road
    assert torch.equal(S.draw_truth(S.shared(data), 5), torch.tensor([SKY_SHIFT], dtype=torch.float64))
    distribution = S.TruthDistribution()
    for level in S.SHARINGS[1:]:
        built = S.sharing(level, data, cars, n_cars)
        first, again, other = (S.draw_truth(built, seed) for seed in (5, 5, 6))
        assert torch.equal(first, again) and not torch.equal(first, other)
        assert first.shape == (built.n_rows, 2)
    cars_level = S.draw_truth(S.per_car(data, cars), 7)
    spread = (cars_level - torch.tensor(SKY_SHIFT, dtype=torch.float64)).std()
    assert 0.5 * distribution.car_sd < float(spread) < 2 * distribution.car_sd
    both = S.camera_and_car(data, cars)
    residual = S.draw_truth(both, 7)[both.rows[:, 1] != S.NO_INDEX]
    assert float(residual.abs().max()) < 5 * distribution.residual_sd
    with pytest.raises(SDMInputError, match="car_sd"):
        S.TruthDistribution(car_sd=-0.1)


def test_render_targets_shared_case_is_the_paper_target(road):
    data, _, _ = road
    level = S.shared(data)
    targets = S.render_targets(data, torch.tensor([SKY_SHIFT], dtype=torch.float64), level.param_index)
    assert torch.equal(targets, data.targets)  # the set was built with SKY_SHIFT


def test_render_targets_moves_each_point_by_its_rows(road):
    data, cars, n_cars = road
    level = S.camera_and_car(data, cars, n_cars)
    truth = S.draw_truth(level, 2)
    targets = S.render_targets(data, truth, level.param_index)
    for index in range(len(data)):
        start, stop = int(data.offsets[index]), int(data.offsets[index + 1])
        expected = torch.zeros(data.camera.screen_shape, dtype=torch.bool)
        for point in range(start, stop):  # one point at a time: its own shift, its own pixel
            rows = level.param_index[point]
            shift = (float(truth[rows[0], 0] + truth[rows[1], 0]), float(truth[rows[0], 1] + truth[rows[1], 1]))
            expected |= shifted_target(data.points[point:point + 1], shift, data.camera)
        assert torch.equal(targets[index], expected)
    with pytest.raises(SDMInputError, match="theta"):
        S.render_targets(data, truth[:, :1], level.param_index)
    with pytest.raises(SDMInputError, match="param_index"):
        S.render_targets(data, truth[:-1], level.param_index)


def test_units_and_totals(road):
    data, cars, n_cars = road
    per_car = S.per_car(data, cars, n_cars)
    car_units = S.units(data, per_car.param_index, per_car.n_rows)
    assert torch.equal(car_units.rows[:, 0], torch.arange(per_car.n_rows))  # a unit per row, in row order
    truth = S.draw_truth(per_car, 1)
    assert torch.equal(S.theta_from_totals(S.unit_totals(truth, car_units), car_units, per_car.n_rows), truth)
    both = S.camera_and_car(data, cars, n_cars)
    units = S.units(data, both.param_index, both.n_rows)
    assert len(units) == per_car.n_rows  # a configuration sees its cars' totals
    theta = S.draw_truth(both, 1)
    totals = S.unit_totals(theta, units)
    assert torch.equal(totals[units.point_unit], S.point_shifts(theta, both.param_index))
    assert torch.equal(units.offsets, torch.cat((torch.zeros(1, dtype=torch.int64),
                                                 torch.bincount(units.config, minlength=len(data)).cumsum(0))))
    with pytest.raises(SDMInputError, match="units"):
        S.theta_from_totals(totals, units, both.n_rows)
    shared_units = S.units(data, S.shared(data).param_index)
    with pytest.raises(SDMInputError, match="units"):
        S.theta_from_totals(torch.zeros(len(shared_units), 2, dtype=torch.float64), shared_units, 1)


def test_distances_and_summary():
    estimate = torch.tensor([[0.0, 0.0], [3.0, 4.0], [1.0, 0.0], [0.0, 2.0]], dtype=torch.float64)
    distances = S.row_distances(estimate, torch.zeros(4, 2, dtype=torch.float64))
    assert distances.tolist() == [0.0, 5.0, 1.0, 2.0]
    summary = S.summarise_distances(distances, hidden=torch.tensor([False, True, False, False]), hidden_without_row=2)
    assert (summary.mean, summary.median, summary.q3, summary.counted, summary.hidden) == (1.0, 1.0, 1.5, 3, 3)
    empty = S.summarise_distances(distances, hidden=torch.ones(4, dtype=torch.bool))
    assert empty.counted == 0 and math.isnan(empty.mean)
    with pytest.raises(SDMInputError, match="hidden"):
        S.summarise_distances(distances, hidden=torch.ones(3, dtype=torch.bool))
    with pytest.raises(SDMInputError, match="truth"):
        S.row_distances(estimate, torch.zeros(3, 2, dtype=torch.float64))


def test_cars_of_points_follow_the_rmin_winner():
    """The test helper's car index: overlapping discs give each pixel to the nearer car."""
    centres = torch.tensor([[0.0, 2.0, 15.0], [0.6, 2.0, 30.0]], dtype=torch.float64)
    configuration = build_configuration(centres)
    cars = cars_of(configuration)
    assert set(cars.tolist()) == {0, 1}
    data = ConfigurationSet.from_configurations([configuration])
    assert data.points.shape[0] == cars.shape[0]

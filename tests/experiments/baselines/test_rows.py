"""CMA-ES and the floor per configuration on per-row shifts (sdm.experiments.baselines.rows)."""
from __future__ import annotations

import pytest
import torch

pytest.importorskip("cma")

from sdm import sharing as S
from sdm.experiments.baselines import rows
from sdm.experiments.baselines.floor import FloorSettings
from sdm.errors import SDMInputError
from sdm.sky import add_target_noise, shifted_target

from sharing_scenes import car_grid_scene, road_set


def reference_mismatch(points, unit, target, candidate, camera) -> int:
    """The straightforward count: render the points moved by their units' shifts, count the differing pixels."""
    shifts = torch.as_tensor(candidate, dtype=torch.float64).view(-1, 2)[unit]
    return int((shifted_target(points, shifts, camera) ^ target).sum())


@pytest.fixture(scope="module")
def scene():
    data, cars, n_cars = road_set(5, seed=9)
    noise_level = S.camera_and_car(data, cars, n_cars)
    truth = S.draw_truth(noise_level, 11)
    shifted = S.shifted_set(data, truth, noise_level.param_index)
    units = S.units(shifted, noise_level.param_index, noise_level.n_rows)
    return shifted, units, S.unit_totals(truth, units)


def test_count_equals_reference(scene):
    data, units, totals = scene
    generator = torch.Generator().manual_seed(0)
    for index in range(len(data)):
        objective = rows.configuration_objective(data, units, index)
        first, last = int(units.offsets[index]), int(units.offsets[index + 1])
        centre = totals[first:last].reshape(1, -1)
        # candidates near theta* (small moves, pixels shared between cars) and far (discs off screen)
        candidates = torch.cat((centre, centre + 0.05 * torch.randn(7, centre.shape[1], generator=generator,
                                                                     dtype=torch.float64),
                                centre + 3.0 * torch.randn(4, centre.shape[1], generator=generator,
                                                           dtype=torch.float64)))
        noisy = add_target_noise(data.targets[index], 2, torch.Generator().manual_seed(index))
        for target in (data.targets[index], noisy):
            counted = rows.ConfigurationMismatch(objective.points, objective.unit, target, data.camera)
            fast = counted.many(candidates.numpy())
            slow = [reference_mismatch(objective.points, objective.unit, target, c, data.camera) for c in candidates]
            assert fast == slow
        assert objective(centre[0].tolist()) == 0  # the target is the rendering at theta*


def test_count_one_at_a_time_equals_generation(scene):
    data, units, totals = scene
    objective = rows.configuration_objective(data, units, 1)
    candidates = (totals[units.offsets[1]:units.offsets[2]].reshape(1, -1)
                  + 0.1 * torch.randn(6, 2 * objective.n_units, generator=torch.Generator().manual_seed(1),
                                      dtype=torch.float64)).numpy()
    assert objective.many(candidates) == [objective(c) for c in candidates]
    assert objective.evaluations == 12
    with pytest.raises(SDMInputError, match="coordinates"):
        objective.many([[0.0, 0.0]])


def _separate_cars():
    """Two configurations of three cars far apart, a shift per car: the set, the cars' rows, theta* and the units."""
    data, cars, n_cars = car_grid_scene(3, n_configs=2, seed=1, far=40.0)
    noise_level = S.per_car(data, cars, n_cars)
    truth = S.draw_truth(noise_level, 3)
    shifted = S.shifted_set(data, truth, noise_level.param_index)
    return shifted, noise_level, truth, S.units(shifted, noise_level.param_index, noise_level.n_rows)


def test_cmaes_per_configuration_recovers_separate_cars():
    shifted, noise_level, truth, units = _separate_cars()
    result = rows.fit_configurations(shifted, units, rows.RowsCMAESSettings(), seed=2)
    again = rows.fit_configurations(shifted, units, rows.RowsCMAESSettings(), seed=2)
    assert torch.equal(result.totals, again.totals) and torch.equal(result.evaluations, again.evaluations)
    assert result.mismatch.tolist() == [0, 0]  # every car in its pixel cell
    assert bool((result.evaluations <= 150 * 6 + 20).all()) and bool((result.seconds > 0).all())
    theta = S.theta_from_totals(result.totals, units, noise_level.n_rows)
    distances = S.row_distances(theta, truth)
    # a car's exact count is flat over its pixel cell: z / f' metres across (at most about 0.25 m here)
    assert float(distances.max()) < 0.3
    for index in range(len(shifted)):
        objective = rows.configuration_objective(shifted, units, index)
        first, last = int(units.offsets[index]), int(units.offsets[index + 1])
        assert reference_mismatch(objective.points, objective.unit, shifted.targets[index],
                                  result.totals[first:last], shifted.camera) == int(result.mismatch[index])


def test_a_start_whose_rows_share_memory_is_copied():
    """One shared start for every unit, as an expanded view: each configuration's search writes its own rows."""
    shifted, _, _, units = _separate_cars()
    start = torch.tensor([0.5, 0.3], dtype=torch.float64)
    viewed = rows.fit_configurations(shifted, units, rows.RowsCMAESSettings(), seed=2,
                                     theta0=start.expand(len(units), 2))
    copied = rows.fit_configurations(shifted, units, rows.RowsCMAESSettings(), seed=2,
                                     theta0=start.expand(len(units), 2).clone())
    assert torch.equal(viewed.totals, copied.totals) and len(set(map(tuple, viewed.totals.tolist()))) > 1
    assert torch.equal(start, torch.tensor([0.5, 0.3], dtype=torch.float64))  # the caller's tensor untouched


def test_floor_per_configuration_is_in_theta_stars_region(scene):
    data, units, totals = scene
    settings = rows.RowsFloorSettings(evaluations_per_unknown=50, floor=FloorSettings(refine_tol=1e-4,
                                                                                     extent_tol=1e-4))
    floor = rows.floor_configurations(data, units, totals, settings, seed=0, configs=[0, 2])
    assert floor.min_mismatch.tolist() == [0, 0, 0, 0, 0] and floor.mismatch_at_truth[[0, 2]].tolist() == [0, 0]
    for index in (0, 2):  # without noise theta* is a minimiser: the floor is theta* itself
        objective = rows.configuration_objective(data, units, index)
        first, last = int(units.offsets[index]), int(units.offsets[index + 1])
        assert torch.equal(floor.totals[first:last], totals[first:last])
        assert objective(floor.centre_totals[first:last].reshape(-1).tolist()) == 0  # the region's centre too
        assert floor.evaluations[index] > 0
    untouched = slice(int(units.offsets[1]), int(units.offsets[2]))
    assert torch.equal(floor.totals[untouched], totals[untouched])
    noisy = data.with_targets(torch.stack([add_target_noise(t, 3, torch.Generator().manual_seed(i))
                                           for i, t in enumerate(data.targets)]))
    noisy_floor = rows.floor_configurations(noisy, units, totals, settings, seed=0, configs=[0])
    assert int(noisy_floor.min_mismatch[0]) <= int(noisy_floor.mismatch_at_truth[0])
    objective = rows.configuration_objective(noisy, units, 0)
    own = slice(0, int(units.offsets[1]))
    least = int(noisy_floor.min_mismatch[0])
    assert objective(noisy_floor.totals[own].reshape(-1).tolist()) == least  # a minimiser the search knows
    gap = (noisy_floor.totals[own] - totals[own]).norm()
    for other in (noisy_floor.centre_totals, noisy_floor.search_totals):  # the nearest to theta* of those at least
        if objective(other[own].reshape(-1).tolist()) == least:
            assert gap <= (other[own] - totals[own]).norm()


def test_settings_and_arguments_checked(scene):
    data, units, _ = scene
    with pytest.raises(SDMInputError, match="evaluations_per_unknown"):
        rows.RowsCMAESSettings(evaluations_per_unknown=0)
    with pytest.raises(SDMInputError, match="sigma0"):
        rows.RowsFloorSettings(sigma0=-1.0)
    with pytest.raises(SDMInputError, match="units"):
        rows.fit_configurations(data.subset([0, 1]), units)
    with pytest.raises(SDMInputError, match="theta0"):
        rows.fit_configurations(data, units, theta0=torch.zeros(len(units) + 1, 2))
    with pytest.raises(SDMInputError, match="truth"):
        rows.floor_configurations(data, units, torch.zeros(1, 2))
    with pytest.raises(SDMInputError, match="configs"):
        rows.fit_configurations(data, units, configs=[len(data)])
    assert rows.RowsCMAESSettings(evaluations_per_unknown=10).cmaes(6).budget == 60


def test_block_sweeps_spend_the_joint_budget_and_never_count_more(scene):
    data, units, totals = scene
    settings = rows.RowsCMAESSettings(evaluations_per_unknown=30, sigma0=0.1)
    start = (totals + 0.2).clone()
    blocks = rows.fit_blocks(data, units, settings, seed=4, theta0=start, sweeps=2)
    again = rows.fit_blocks(data, units, settings, seed=4, theta0=start, sweeps=2)
    assert torch.equal(blocks.totals, again.totals)
    for index in range(len(data)):
        first, last = int(units.offsets[index]), int(units.offsets[index + 1])
        objective = rows.configuration_objective(data, units, index)
        at_start = objective(start[first:last].reshape(-1).tolist())
        assert int(blocks.mismatch[index]) <= at_start  # each block keeps its start unless it counts less
        assert int(blocks.mismatch[index]) == objective(blocks.totals[first:last].reshape(-1).tolist())
        n_units = last - first
        # each of the 2 U block searches gets 30 counts, at most one generation more, plus its start's count
        assert int(blocks.evaluations[index]) <= 2 * n_units * (30 + 6 + 1) + 1
    assert int(blocks.mismatch.sum()) < sum(
        rows.configuration_objective(data, units, i)(start[int(units.offsets[i]):int(units.offsets[i + 1])]
                                                     .reshape(-1).tolist()) for i in range(len(data)))
    with pytest.raises(SDMInputError, match="sweeps must be a positive integer"):
        rows.fit_blocks(data, units, settings, sweeps=0)


def test_the_regularised_search_stays_near_its_start(scene):
    data, units, totals = scene
    start = (totals + 0.15).clone()
    plain = rows.fit_configurations(data, units, rows.RowsCMAESSettings(evaluations_per_unknown=40), seed=1,
                                    theta0=start)
    zero = rows.fit_configurations(data, units, rows.RowsCMAESSettings(evaluations_per_unknown=40, penalty=0.0),
                                   seed=1, theta0=start)
    assert torch.equal(plain.totals, zero.totals)
    heavy = rows.fit_configurations(data, units, rows.RowsCMAESSettings(evaluations_per_unknown=40, penalty=1e6),
                                    seed=1, theta0=start)
    moved = lambda fit: float((fit.totals - start).norm(dim=1).mean())  # noqa: E731
    assert moved(heavy) < 0.1 * moved(plain)
    objective = rows.configuration_objective(data, units, 0)
    base = totals[:int(units.offsets[1])].reshape(-1).tolist()
    away = [base[0] + 0.1] + base[1:]
    penalised = rows.Penalised(objective, base, 2.0)
    assert penalised(away) == pytest.approx(objective(away) + 2.0)  # (0.1 m)^2 away: one weight
    with pytest.raises(SDMInputError, match="penalty"):
        rows.RowsCMAESSettings(penalty=-1.0)

"""The soft-silhouette baseline on per-row shifts (parameters attached to points)."""
from __future__ import annotations

import pytest
import torch

from sdm import sharing as S
from sdm.experiments.baselines import silhouette
from sdm.experiments.baselines.silhouette import SilhouetteSettings
from sdm.errors import SDMInputError

from sharing_scenes import car_grid_scene, road_set

FAST = SilhouetteSettings(steps=6, batch_size=4)


@pytest.fixture(scope="module")
def road():
    return road_set(4, seed=2)


def test_one_row_equals_the_shared_path(road):
    data, _, _ = road
    shared = silhouette.fit(data, FAST, seed=3)
    noise_level = S.shared(data)
    rows = silhouette.fit(data, FAST, seed=3, theta0=torch.zeros(1, 2, dtype=torch.float64),
                          param_index=noise_level.param_index)
    assert rows.theta.shape == (1, 2)
    assert tuple(rows.theta[0].tolist()) == shared.theta
    assert rows.history["loss"] == shared.history["loss"]


def test_rows_per_configuration_move_towards_their_shifts():
    data, cars, n_cars = car_grid_scene(4, n_configs=3, seed=5, far=30.0)
    noise_level = S.per_configuration(data)
    truth = S.draw_truth(noise_level, 1)
    shifted = S.shifted_set(data, truth, noise_level.param_index)
    settings = SilhouetteSettings(steps=24, batch_size=len(shifted))
    start = torch.zeros(noise_level.n_rows, 2, dtype=torch.float64)
    runs = silhouette.fit_runs([shifted, shifted], settings, [0, 1], theta0=start, param_index=noise_level.param_index)
    for result in runs:
        distances = S.row_distances(result.theta, truth)
        assert float(distances.max()) < 0.5 * float(S.row_distances(start, truth).min())
    assert torch.equal(runs[0].theta, runs[1].theta)  # full batch: the seed draws nothing
    single = silhouette.fit(shifted, settings, 0, theta0=start, param_index=noise_level.param_index)
    assert torch.equal(single.theta, runs[0].theta)  # a run of many is the run alone


def test_camera_and_car_rows_fit(road):
    data, cars, n_cars = road
    noise_level = S.camera_and_car(data, cars, n_cars)
    truth = S.draw_truth(noise_level, 4)
    shifted = S.shifted_set(data, truth, noise_level.param_index)
    units = S.units(shifted, noise_level.param_index, noise_level.n_rows)
    result = silhouette.fit(shifted, SilhouetteSettings(steps=12, batch_size=len(shifted)), 0,
                            theta0=torch.zeros(noise_level.n_rows, 2, dtype=torch.float64), param_index=noise_level.param_index)
    before = S.row_distances(torch.zeros(len(units), 2, dtype=torch.float64), S.unit_totals(truth, units))
    after = S.row_distances(S.unit_totals(result.theta, units), S.unit_totals(truth, units))
    assert float(after.median()) < 0.5 * float(before.median())


def test_bad_index_and_theta_named(road):
    data, cars, _ = road
    noise_level = S.per_car(data, cars)
    start = torch.zeros(noise_level.n_rows, 2, dtype=torch.float64)
    with pytest.raises(SDMInputError, match="param_index"):
        silhouette.fit(data, FAST, theta0=start, param_index=noise_level.param_index[:-1])
    with pytest.raises(SDMInputError, match="param_index.*theta"):
        silhouette.fit(data, FAST, theta0=start[:-1], param_index=noise_level.param_index)
    with pytest.raises(SDMInputError, match="row .* of theta moves no point"):
        silhouette.fit(data, FAST, theta0=torch.zeros(noise_level.n_rows + 1, 2), param_index=noise_level.param_index)
    with pytest.raises(SDMInputError, match="theta0"):
        silhouette.fit(data, FAST, theta0=(0.0, 0.0), param_index=noise_level.param_index)

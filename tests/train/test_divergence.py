"""Divergence is named: a start or a last theta beyond THETA_BOUND, a run whose points are all off the screen, or a run
whose targets pull nothing stops with an SDMInputError naming the run, the step and the setting to change."""
from __future__ import annotations

import re

import pytest
import torch

from scenes import configuration_set
from sdm import ConfigurationSet, TrainSettings, build_configuration, train
from sdm.errors import SDMInputError
from sdm.train import THETA_BOUND, Refinement, refine_runs, train_runs


@pytest.fixture(scope="module")
def data():
    return configuration_set(32, seed=3)


@pytest.fixture(scope="module")
def near():
    """16 configurations of three cars 5-6 m ahead: a shift of 9.5 m sideways puts every point off the screen."""
    generator = torch.Generator().manual_seed(0)
    configurations = []
    for _ in range(16):
        z = 5 + torch.rand(3, generator=generator, dtype=torch.float64)
        x = torch.rand(3, generator=generator, dtype=torch.float64) - 0.5
        configurations.append(build_configuration(torch.stack((x, 1.5 + 0 * z, z), 1)))
    return ConfigurationSet.from_configurations(configurations)


@pytest.mark.parametrize("theta0", [(1e9, 1e9), (50.0, 0.0)], ids=["far", "sideways"])
def test_a_start_beyond_the_bound_is_refused(data, theta0):
    """On main these returned theta near 1e9, and (41.8, 0.61) from 50 m sideways, without a word."""
    with pytest.raises(SDMInputError, match=r"theta0\[0\] lies beyond the bound of 10\.0 m per component"):
        train(data, TrainSettings(), progress=False, theta0=theta0)


@pytest.mark.parametrize("lr", [1e300, 1.0])
def test_a_theta_that_ends_beyond_the_bound_names_the_run_the_step_and_lr(data, lr):
    """On main lr=1e300 returned theta near 1e299."""
    settings = [TrainSettings(lr=lr, seed=seed) for seed in (0, 1)]
    with pytest.raises(SDMInputError, match=r"theta of run 0 ended beyond the bound of 10\.0 m per component "
                                            r"\(THETA_BOUND\), where it stayed from step 1 "
                                            rf"\(rate {re.escape(repr(lr))}\) on: the run diverged; lower lr"):
        train_runs(data, [data.targets] * 2, settings)


def test_a_row_rate_that_diverges_names_row_rate(data):
    """On main row_rate=1e300 returned theta near 1e299."""
    index = torch.repeat_interleave(torch.arange(len(data)), data.counts)
    with pytest.raises(SDMInputError, match=r"theta of run 0 ended beyond the bound .* lower lr or row_rate"):
        train_runs(data, [data.targets], [TrainSettings(lr=1e-4)], param_index=index,
                   row_rate=torch.full((len(data),), 1e300, dtype=torch.float64))


def test_a_refinement_that_diverges_is_named(data):
    history = train_runs(data, [data.targets], [TrainSettings(lr=1e-4, rule="closed_centred_r1")])
    with pytest.raises(SDMInputError, match=r"theta of run 0 ended beyond the bound .* from step 1[0-9] "):
        refine_runs(data, [data.targets], [TrainSettings(lr=1e300, rule="closed_centred_r1")], history,
                    Refinement("closed_centred_r1", 1, pass_steps=2))


@pytest.mark.parametrize("theta0", [(9.5, 0.0), (0.0, 9.5)])
def test_a_start_with_every_point_off_the_screen_is_refused(near, theta0):
    """Within the bound, but no point lands: on main the run kept its start, its flow zero at every step."""
    assert max(abs(v) for v in theta0) < THETA_BOUND
    with pytest.raises(SDMInputError, match=r"theta0: every point of run 0 is off the 128 x 256 screen at its start"):
        train(near, TrainSettings(), progress=False, theta0=theta0)


def test_targets_without_an_active_pixel_are_refused(data):
    """On main the run returned its start: no target block pulls any point."""
    with pytest.raises(SDMInputError, match=r"targets\[1\] holds no active pixel: the flow vanishes for every point "
                                            r"of run 1"):
        train_runs(data, [data.targets, torch.zeros_like(data.targets)], [TrainSettings(seed=0), TrainSettings(seed=1)])


def test_an_early_overshoot_that_comes_back_is_no_divergence():
    """At the tuning grid's largest rate (1e-3) the first steps overshoot far beyond the bound and come back: the
    run is a result (tests/baselines/test_baselines.py recovers the shift so within 5e-3 m)."""
    data = configuration_set(64, seed=5)
    history = train(data, TrainSettings(lr=1e-3, n_epoch=2), progress=False)
    assert float(history.theta.abs().max()) > THETA_BOUND
    assert max(abs(value) for value in history.final_theta) < 1.0

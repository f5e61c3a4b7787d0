"""The schedule's refinement passes (closed_centred_r1, then group_crossing at zoom 0)."""
from dataclasses import replace

import pytest
import torch

from scenes import configuration_set
from sdm.errors import SDMInputError
from sdm.mapping import native
from sdm.experiments import noisy_targets, train_group
from sdm.sky import SKY_SHIFT
from sdm.train import Refinement, TrainSettings, parse_schedule, refine_runs, refine_seed, train_runs

BASE = TrainSettings(lr=1e-4, n_epoch=1, s=4, flow="closed_centred_r1")


@pytest.fixture(scope="module")
def small():
    return configuration_set(64, seed=11)


def test_refined_runs_packed_equal_each_run_refined_alone(small):
    """Three runs refined together (R = 3, packed steps) have each run's history refined alone (R = 1) to the bit:
    group_crossing's flow values are exact binary fractions, so the packed sum cannot round otherwise."""
    settings = [replace(BASE, seed=seed) for seed in (4, 9, 4)]
    targets = [noisy_targets(small.targets, 2, 1), noisy_targets(small.targets, 1, 5), small.targets]
    refinement = Refinement("group_crossing", 3)
    together = refine_runs(small, targets, settings, train_runs(small, targets, settings), refinement)
    main_steps = 5 * (64 // 16)
    assert together.theta.shape == (main_steps + 3 * (64 // 16) + 1, 3, 2)
    for run, (one, run_targets) in enumerate(zip(settings, targets)):
        alone = refine_runs(small, [run_targets], [one], train_runs(small, [run_targets], [one]), refinement)
        assert torch.equal(together.theta[:, run], alone.theta[:, 0]), run
    assert not torch.equal(together.theta[main_steps:, 0], together.theta[main_steps, 0].expand(4 * 3 + 1, 2))


@pytest.mark.skipif(not native.enabled(), reason="no C compiler: the compiled kernel is not built")
def test_the_compiled_refinement_equals_the_torch_path_bit_for_bit(small, monkeypatch):
    """The passes run in one sdm_train call (levels 0, 0, ...; group_crossing's mode) and give the torch
    path's theta history to the bit and its loss (the mismatch count) exactly."""
    settings = [replace(BASE, seed=seed) for seed in (3, 8)]
    targets = [noisy_targets(small.targets, 3, 2), noisy_targets(small.targets, 1, 6)]
    refinement = Refinement("group_crossing", 3)
    calls = []
    program = native.train_program
    monkeypatch.setattr(native, "train_program", lambda *args, **kwargs: calls.append(1) or program(*args, **kwargs))
    compiled = refine_runs(small, targets, settings, train_runs(small, targets, settings), refinement)
    assert len(calls) == 2
    monkeypatch.setattr(native, "enabled", lambda: False)
    torch_path = refine_runs(small, targets, settings, train_runs(small, targets, settings), refinement)
    assert len(calls) == 2
    assert torch.equal(compiled.theta, torch_path.theta)
    main_steps = 5 * (64 // 16)  # before: closed_centred_r1's loss in metres, summed in another order
    scale = float(torch_path.loss[:main_steps].abs().max())
    assert float((compiled.loss[:main_steps] - torch_path.loss[:main_steps]).abs().max()) <= 1e-12 * scale
    assert torch.equal(compiled.loss[main_steps:], torch_path.loss[main_steps:])
    assert bool((compiled.loss[main_steps:] == compiled.loss[main_steps:].round()).all())  # pixel counts


def test_refinement_passes_continue_the_halving_at_the_finest_level(small):
    """Pass i runs at level zoom, at four times the last level's rate times lr_decay^i (rate_from 2), shuffled by
    its own seed; rate_from 1 starts at twice the last level's."""
    history = train_group(small, [small.targets], BASE, [7], refine=Refinement("group_crossing", 3))
    per_pass = 64 // 16
    assert history.level[-3 * per_pass:].tolist() == [0] * (3 * per_pass)
    rates = history.lr[-3 * per_pass:].reshape(3, per_pass)
    assert rates[:, 0].tolist() == [1e-4 * 0.5**2, 1e-4 * 0.5**3, 1e-4 * 0.5**4]
    assert Refinement("group_crossing", 2, rate_from=1).rates(BASE) == [1e-4 * 0.5**3, 1e-4 * 0.5**4]
    assert bool((rates == rates[:, :1]).all())
    assert refine_seed(7) != 7 and refine_seed(7) != refine_seed(8)


def test_refinement_keeps_the_true_shift_without_noise(small):
    """Started at theta* on noise-free targets, group_crossing's passes do not move it (exact fixed point)."""
    settings = BASE
    start = train_runs(small, [small.targets], [settings], theta0=[SKY_SHIFT])
    assert torch.equal(start.theta[-1, 0], torch.tensor(SKY_SHIFT, dtype=torch.float64))
    stay = refine_runs(small, [small.targets], [settings], start, Refinement("group_crossing", 2))
    moved = (stay.theta[len(start.theta):, 0] - torch.tensor(SKY_SHIFT, dtype=torch.float64)).abs().max()
    assert float(moved) == 0


def test_the_refinement_moves_c_with_fit_depth_unless_told_not_to(small):
    """With fit_depth the schedule holds c below depth_zoom (1); the refinement's zoom-0 passes move it
    (moves_c, the default) at depth_lr_scale times their rate, or leave it where the schedule put it."""
    settings = [replace(BASE, seed=5, fit_depth=True)]
    targets = [noisy_targets(small.targets, 2, 3)]
    history = train_runs(small, targets, settings)
    per_pass = 64 // 16
    moving = refine_runs(small, targets, settings, history, Refinement("group_crossing", 2))
    held = refine_runs(small, targets, settings, history, Refinement("group_crossing", 2, moves_c=False))
    end = history.theta[-1, 0]
    assert bool((held.theta[-2 * per_pass:, 0, 2] == end[2]).all())
    assert float((moving.theta[-1, 0, 2] - end[2]).abs()) > 0
    # (a, b) move in both; the held run's passes are the moving run's with the c column's rate at zero
    assert not torch.equal(held.theta[-1, 0, :2], end[:2])


@pytest.mark.parametrize("kwargs,match", [({"flow": "no-such"}, "flow"), ({"epochs": 0}, "epochs"),
                                          ({"epochs": 2.0}, "epochs"), ({"epochs": True}, "epochs"),
                                          ({"rate_from": -1}, "rate_from"), ({"rate_from": 1.5}, "rate_from"),
                                          ({"moves_c": 1}, "moves_c")])
def test_bad_refinements_are_refused_naming_the_field(kwargs, match):
    with pytest.raises(SDMInputError, match=match):
        Refinement(**kwargs)


@pytest.mark.parametrize("name,expected", [
    ("closed_centred_r1", ("closed_centred_r1", None)),
    ("closed_centred_r1+group_crossing:3", ("closed_centred_r1", Refinement("group_crossing", 3))),
    ("paper+group_crossing", ("paper", Refinement("group_crossing", 4))),
])
def test_schedules_are_parsed_by_name(name, expected):
    assert parse_schedule(name) == expected


@pytest.mark.parametrize("name,match", [("closedd", "flow"), ("paper+nope:2", "flow"), ("paper+group_crossing:0", ":"),
                                        ("paper+group_crossing:x", ":"), (3, "schedule")])
def test_bad_schedules_are_refused_naming_the_part(name, match):
    with pytest.raises(SDMInputError, match=match):
        parse_schedule(name)

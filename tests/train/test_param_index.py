"""Parameters attached to points: ``train_runs(param_index=)`` against the reference loop, compiled and not.

The paper's case is one row shared by every point; the fundamental problem attaches rows to points (one per
configuration, one per car, a camera row plus a residual per car). The engine must give every row the history of
``tests/train_reference.py`` (the plain loop, one layer call per mini-batch, theta gathered per point), to the bit,
on the compiled path and on the torch path.
"""
from __future__ import annotations

import pytest
import torch

from sdm.errors import SDMInputError
from sdm.mapping import native
from sdm.mapping.crossing import rigid_groups
from sdm.sky import SKY_SHIFT, shifted_target
from sdm.train import Refinement, RunsHistory, TrainSettings, rates_per_point, refine_runs, train_runs

from scenes import configuration_set
from train_reference import reference_train


def point_config(data) -> torch.Tensor:
    """``(P,)`` int64 the configuration of each point."""
    return torch.repeat_interleave(torch.arange(len(data)), data.counts)


def per_car(data) -> torch.Tensor:
    """``(P,)`` one row per disc depth of each configuration (a car of the scenes: one depth per car)."""
    group, _ = rigid_groups(data.points[:, :2], data.points[:, 2], point_config(data))
    return group


def rows_of(data, sharing: str) -> torch.Tensor:
    if sharing == "shared":
        return torch.zeros(data.points.shape[0], dtype=torch.int64)
    if sharing == "configuration":
        return point_config(data)
    if sharing == "car":
        return per_car(data)
    # "camera + car": row 0 the camera, moved by every point; rows 1.. a residual per car
    return torch.stack((torch.zeros(data.points.shape[0], dtype=torch.int64), per_car(data) + 1), 1)


def true_rows(n_rows: int, seed: int) -> torch.Tensor:
    """``(K, 2)`` theta* per row: the paper's shift plus a few centimetres per row."""
    generator = torch.Generator().manual_seed(seed)
    return torch.tensor(SKY_SHIFT, dtype=torch.float64) + 0.05 * torch.randn(n_rows, 2, generator=generator,
                                                                              dtype=torch.float64)


def row_targets(data, param_index: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
    """``(N, H, W)`` bool: each configuration's points moved by their rows' sums, rendered as the paper's targets."""
    rows = param_index.reshape(data.points.shape[0], -1)
    shift = theta[rows].sum(1)
    offsets = data.offsets.tolist()
    return torch.stack([shifted_target(data.points[lo:hi], shift[lo:hi]) for lo, hi in zip(offsets, offsets[1:])])


SHARINGS = ["shared", "configuration", "car", "camera + car"]


@pytest.mark.parametrize("sharing", SHARINGS)
@pytest.mark.parametrize("rule", ["paper", "closed_centred_r1"])
@pytest.mark.parametrize("compiled", [True, False])
def test_rows_follow_the_reference_loop_bit_for_bit(sharing, rule, compiled):
    if compiled and not native.enabled():
        pytest.skip("no C compiler: the compiled kernel is not built")
    data = configuration_set(48, seed=31)
    index = rows_of(data, sharing)
    n_rows = int(index.max()) + 1
    truth = true_rows(n_rows, seed=5)
    data = data.with_targets(row_targets(data, index, truth))
    settings = [TrainSettings(lr=3e-4, n_epoch=2, s=3, rule=rule, seed=seed) for seed in (1, 2)]
    starts = [torch.zeros(n_rows, 2, dtype=torch.float64), 0.01 * torch.ones(n_rows, 2, dtype=torch.float64)]
    if compiled:
        runs = train_runs(data, [data.targets] * 2, settings, theta0=starts, param_index=index)
    else:
        with native.disabled():
            runs = train_runs(data, [data.targets] * 2, settings, theta0=starts, param_index=index)
    per_epoch = len(data) // 16
    assert runs.theta.shape == (4 * 2 + 1, 2, n_rows, 2)
    assert runs.theta_steps.tolist() == list(range(0, 8 * per_epoch + 1, per_epoch))
    for run in range(2):
        theta, loss = reference_train(data, settings[run], theta0=starts[run], param_index=index)
        assert torch.equal(runs.theta[:, run], theta[runs.theta_steps]), run
        assert float((runs.loss[:, run] - loss).abs().max()) <= 1e-12 * float(loss.abs().max())
    assert not torch.equal(runs.theta[0], runs.theta[-1])  # it trained
    if sharing != "shared":  # each row at its own rate
        row_rate = rates_per_point(index)
        with native.disabled() if not compiled else _nothing():
            scaled = train_runs(data, [data.targets], settings[:1], param_index=index, row_rate=row_rate)
        theta, _ = reference_train(data, settings[0], theta0=torch.zeros(n_rows, 2, dtype=torch.float64),
                                   param_index=index, row_rate=row_rate)
        assert torch.equal(scaled.theta[:, 0], theta[scaled.theta_steps])
        assert not torch.equal(scaled.theta[-1, 0], runs.theta[-1, 0])


def test_one_row_for_every_point_is_the_shared_shift():
    """param_index all zeros (K = 1) trains the paper's shift: the same numbers as no param_index."""
    data = configuration_set(48, seed=32)
    settings = [TrainSettings(lr=3e-4, n_epoch=1, seed=4, rule="closed_centred_r1")]
    shared = train_runs(data, [data.targets], settings)
    rows = train_runs(data, [data.targets], settings, param_index=torch.zeros(data.points.shape[0], dtype=torch.int32))
    assert torch.equal(rows.theta[:, :, 0], shared.theta[rows.theta_steps])
    assert torch.equal(rows.loss, shared.loss)


@pytest.mark.parametrize("sharing", ["configuration", "car", "camera + car"])
def test_the_refinement_moves_rows_as_the_torch_path(sharing):
    """group_crossing's compiled refinement on rows equals the torch path's, and keeps every row's theta* fixed."""
    data = configuration_set(32, seed=33)
    index = rows_of(data, sharing)
    n_rows = int(index.max()) + 1
    truth = true_rows(n_rows, seed=6)
    if sharing == "camera + car":
        truth[0] = 0.0  # the camera row's share is in the residuals
    data = data.with_targets(row_targets(data, index, truth))
    settings = [TrainSettings(lr=3e-4, n_epoch=1, s=2, rule="closed_centred_r1", seed=3)]
    starts = [truth + 1e-3]
    runs = {}
    for compiled in (True, False):
        with native.disabled() if not compiled else _nothing():
            history = train_runs(data, [data.targets], settings, theta0=starts, param_index=index)
            runs[compiled] = refine_runs(data, [data.targets], settings, history,
                                         Refinement("group_crossing", 2, pass_steps=3), param_index=index)
    assert torch.equal(runs[True].theta, runs[False].theta)
    # the rows after every epoch (2 steps) of the zooms, then after every step of the passes (3 steps each)
    assert runs[True].theta_steps.tolist() == [0, 2, 4, 6, 7, 8, 9, 10, 11, 12]
    at_truth = RunsHistory(truth[None, None], torch.zeros(0, 1, dtype=torch.float64), torch.zeros(0, dtype=torch.int64),
                           torch.zeros(0, dtype=torch.float64), settings)
    fixed = refine_runs(data, [data.targets], settings, at_truth, Refinement("group_crossing", 1), param_index=index)
    assert torch.equal(fixed.theta[-1, 0], truth)  # without noise, theta* pulls nothing


class _nothing:
    def __enter__(self):
        return None

    def __exit__(self, *exc):
        return False


def test_a_row_learns_from_its_own_points_only():
    """Per configuration: a configuration whose target is its points at its own theta* pulls its row towards it."""
    data = configuration_set(64, seed=34)
    index = point_config(data)
    truth = true_rows(len(data), seed=7)
    data = data.with_targets(row_targets(data, index, truth))
    settings = [TrainSettings(lr=3e-3, n_epoch=8, s=4, seed=0)]
    runs = train_runs(data, [data.targets], settings, param_index=index)
    start = truth.norm(dim=1)
    end = (runs.theta[-1, 0] - truth).norm(dim=1)
    assert float(end.median()) < 0.1 * float(start.median())


@pytest.mark.parametrize("bad,message", [
    (lambda p: torch.zeros(p - 1, dtype=torch.int64), "one entry per point"),
    (lambda p: -torch.ones(p, dtype=torch.int64), "must not be negative"),
    (lambda p: torch.zeros(p, dtype=torch.float64), "must hold integers"),
    (lambda p: torch.full((p,), 2, dtype=torch.int64), "row 0 of theta moves no point"),
    (lambda p: torch.zeros(p, 0, dtype=torch.int64), "at least one row per point"),
    (lambda p: torch.zeros(p, 2, 2, dtype=torch.int64), "shape (P,) or (P, G)"),
])
def test_bad_param_index_is_named(bad, message):
    data = configuration_set(16, seed=35)
    with pytest.raises(SDMInputError, match="param_index") as error:
        train_runs(data, [data.targets], [TrainSettings()], param_index=bad(data.points.shape[0]))
    assert message in str(error.value)


def test_row_rate_is_checked():
    data = configuration_set(16, seed=38)
    index = point_config(data)
    for bad, message in ((torch.ones(15, dtype=torch.float64), r"row_rate must hold one entry per row of param_index \(16\)"),
                         (-torch.ones(16, dtype=torch.float64), "row_rate must be 16 positive"),
                         (torch.ones(16, dtype=torch.int64), "row_rate must be 16 positive")):
        with pytest.raises(SDMInputError, match=message):
            train_runs(data, [data.targets], [TrainSettings()], param_index=index, row_rate=bad)
    with pytest.raises(SDMInputError, match="row_rate needs param_index"):
        train_runs(data, [data.targets], [TrainSettings()], row_rate=torch.ones(1, dtype=torch.float64))


def test_theta0_must_match_the_rows():
    data = configuration_set(16, seed=36)
    index = point_config(data)
    with pytest.raises(SDMInputError, match=r"param_index must lie in \[0, 15\)"):  # an index beyond theta's rows
        train_runs(data, [data.targets], [TrainSettings()], theta0=[torch.zeros(15, 2)], param_index=index)
    with pytest.raises(SDMInputError, match=r"theta0\[0\] must be \(16, 2\)"):
        train_runs(data, [data.targets], [TrainSettings()], theta0=[torch.zeros(16, 3)], param_index=index)
    with pytest.raises(SDMInputError, match="fit_depth"):
        train_runs(data, [data.targets], [TrainSettings(fit_depth=True)], param_index=index)


def test_group_crossing_splits_a_group_between_rows():
    """Two rows inside one depth group: the compiled refinement moves each part as its own group; the torch path,
    whose rule groups by depth alone, refuses."""
    data = configuration_set(16, seed=37)
    index = torch.arange(data.points.shape[0]) % 2  # neighbours of one disc in different rows
    settings = [TrainSettings(s=2, rule="closed_centred_r1")]
    history = train_runs(data, [data.targets], settings, param_index=index)
    if native.enabled():
        refined = refine_runs(data, [data.targets], settings, history, Refinement("group_crossing", 1),
                              param_index=index)
        assert refined.theta.shape[-2:] == (2, 2)
    with native.disabled(), pytest.raises(SDMInputError, match="param_index: group_crossing"):
        refine_runs(data, [data.targets], settings, history, Refinement("group_crossing", 1), param_index=index)


@pytest.mark.parametrize("sharing", ["configuration", "camera + car"])
@pytest.mark.parametrize("compiled", [True, False])
def test_rows_start_at_their_own_first_zoom(sharing, compiled):
    """row_zoom: each row stays at its start above its first zoom and then follows the reference loop, which
    skips its steps there, to the bit on both paths; row_zoom at s everywhere is no row_zoom."""
    if compiled and not native.enabled():
        pytest.skip("no C compiler: the compiled kernel is not built")
    data = configuration_set(48, seed=39)
    index = rows_of(data, sharing)
    n_rows = int(index.max()) + 1
    data = data.with_targets(row_targets(data, index, true_rows(n_rows, seed=8)))
    settings = [TrainSettings(lr=3e-4, n_epoch=2, s=3, seed=2)]
    start = 0.01 * torch.ones(n_rows, 2, dtype=torch.float64)
    first = torch.arange(n_rows, dtype=torch.int64) % 4  # zooms 0..3: every first zoom is some row's
    row_rate = rates_per_point(index)
    with native.disabled() if not compiled else _nothing():
        runs = train_runs(data, [data.targets], settings, theta0=[start], param_index=index, row_rate=row_rate,
                          row_zoom=first)
        plain = train_runs(data, [data.targets], settings, theta0=[start], param_index=index, row_rate=row_rate)
        at_s = train_runs(data, [data.targets], settings, theta0=[start], param_index=index, row_rate=row_rate,
                          row_zoom=torch.full((n_rows,), 3))
    theta, loss = reference_train(data, settings[0], theta0=start, param_index=index, row_rate=row_rate,
                                  row_zoom=first)
    assert torch.equal(runs.theta[:, 0], theta[runs.theta_steps])
    assert float((runs.loss[:, 0] - loss).abs().max()) <= 1e-12 * float(loss.abs().max())
    assert torch.equal(at_s.theta, plain.theta)
    per_zoom = len(runs.theta_steps[1:]) // 4  # records per zoom (one per epoch)
    for zoom in range(4):  # a row of first zoom l is at its start after the zooms above l
        rows = first == zoom
        above = per_zoom * (3 - zoom)
        assert torch.equal(runs.theta[above, 0][rows], start[rows])
        assert not torch.equal(runs.theta[-1, 0][rows], start[rows])  # and it trained below


def test_row_zoom_is_checked():
    data = configuration_set(16, seed=38)
    index = point_config(data)
    settings = [TrainSettings(s=3)]
    for bad, message in ((torch.zeros(15, dtype=torch.int64), r"row_zoom must hold one entry per row of param_index \(16\)"),
                         (torch.zeros(16, dtype=torch.float64), "row_zoom must be 16 integers"),
                         (torch.full((16,), 4, dtype=torch.int64), r"must lie in the schedule's zooms 0 \.\. 3"),
                         (torch.full((16,), -1, dtype=torch.int64), "row_zoom must lie in")):
        with pytest.raises(SDMInputError, match=message):
            train_runs(data, [data.targets], settings, param_index=index, row_zoom=bad)
    with pytest.raises(SDMInputError, match="row_zoom needs param_index"):
        train_runs(data, [data.targets], settings, row_zoom=torch.zeros(1, dtype=torch.int64))

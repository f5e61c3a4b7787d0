"""Every compiled entry point checks its arrays against each other before the kernel reads them, and refine_runs
accepts exactly what train_runs accepts (one shared check): a bad call is an SDMInputError naming the argument,
never memory read or written outside a tensor."""
from __future__ import annotations

import sys
from dataclasses import replace

import pytest
import torch

from scenes import configuration_set
from sdm.errors import SDMInputError
from sdm.mapping import native
from sdm.train import Refinement, TrainSettings, refine_runs, train_runs

SETTINGS = TrainSettings(lr=1e-4, s=4, rule="closed_centred_r1")
REFINE = Refinement("group_crossing", 1, pass_steps=4)
needs_kernel = pytest.mark.skipif(not native.enabled(), reason="no C compiler: the compiled kernel is not built")


@pytest.fixture(scope="module")
def data():
    return configuration_set(32, seed=11)


@pytest.fixture(scope="module")
def per_config(data):
    """(P,) int64: a row of theta per configuration."""
    return torch.repeat_interleave(torch.arange(len(data)), data.counts)


def test_refining_a_history_of_rows_without_its_param_index_is_refused(data, per_config):
    """On main this returned theta read from uninitialised memory (values like 1e-320, different every call)."""
    history = train_runs(data, [data.targets], [SETTINGS], param_index=per_config)
    with pytest.raises(SDMInputError, match="param_index: the history was trained with parameters attached"):
        refine_runs(data, [data.targets], [SETTINGS], history, REFINE)


def test_refining_a_shared_shift_history_with_a_param_index_is_refused(data):
    """On main this corrupted the heap and aborted the process."""
    history = train_runs(data, [data.targets], [SETTINGS])
    with pytest.raises(SDMInputError, match="param_index: the history was trained with one shift a run"):
        refine_runs(data, [data.targets], [SETTINGS], history, REFINE,
                    param_index=torch.arange(data.points.shape[0]) % 2)


def test_refine_refuses_runs_whose_settings_differ_beyond_the_seed(data):
    """On main every run was refined with the first run's settings while the history recorded the others."""
    settings = [SETTINGS, replace(SETTINGS, seed=1, lr=2e-4)]
    history = train_runs(data, [data.targets] * 2, [SETTINGS, replace(SETTINGS, seed=1)])
    with pytest.raises(SDMInputError, match="settings: the runs' settings may differ only in seed"):
        refine_runs(data, [data.targets] * 2, settings, history, REFINE)


def test_refine_refuses_extra_target_sets(data):
    """On main the extra target sets were ignored."""
    history = train_runs(data, [data.targets], [SETTINGS])
    with pytest.raises(SDMInputError, match="targets: one target set per run"):
        refine_runs(data, [data.targets] * 2, [SETTINGS], history, REFINE)


def test_refine_refuses_a_history_of_other_runs_before_any_pass(data, monkeypatch):
    """On main a run-count mismatch failed only after every pass had run; now no program starts."""
    history = train_runs(data, [data.targets] * 2, [SETTINGS, replace(SETTINGS, seed=1)])
    called = []
    monkeypatch.setattr(sys.modules["sdm.train.refine"], "train_steps", lambda *args, **kwargs: called.append(1))
    with pytest.raises(SDMInputError, match="history holds 2 runs, settings 1"):
        refine_runs(data, [data.targets], [SETTINGS], history, REFINE)
    assert not called


@pytest.fixture(scope="module")
def program(data):
    """The keyword arguments of one valid train_program call (one run, the paper's flow at zooms 4..0)."""
    zooms = [4, 3, 2, 1, 0]
    orders = torch.stack([torch.randperm(len(data), generator=torch.Generator().manual_seed(i))[None]
                          for i in range(len(zooms))])
    return dict(points=data.points, pixels=data.pixels, rank=data.rank, offsets=data.offsets, camera=data.camera,
                s=4, zooms=zooms, n_epoch=1, batch_size=16, rates=[1e-4] * 5,
                windows=[native.KernelFlow.PAPER] * 5, orders=orders, targets=[[None] * 4 + [data.targets]],
                theta0=torch.zeros(1, 2, dtype=torch.float64), bases=[data.targets])


@needs_kernel
def test_a_valid_program_runs(program):
    thetas, losses, failed = native.train_program(**program)
    assert thetas.shape == (11, 1, 2) and bool(torch.isfinite(thetas).all()) and int(failed[0]) == -1


@needs_kernel
@pytest.mark.parametrize("change, named", [
    (lambda p, d: dict(theta0=torch.zeros(2, 2, dtype=torch.float64)), "theta0"),
    (lambda p, d: dict(theta0=torch.zeros(1, 3, 2, dtype=torch.float64)), "theta0"),
    (lambda p, d: dict(orders=p["orders"] + 1), "orders must lie in"),
    (lambda p, d: dict(orders=p["orders"][:, :, :-1]), "orders must have shape"),
    (lambda p, d: dict(offsets=d.offsets.flip(0)), "offsets must run from 0"),
    (lambda p, d: dict(pixels=d.pixels[:-1]), "pixels must have shape"),
    (lambda p, d: dict(bases=[d.targets[:-1]]), r"bases\[0\] must have shape"),
    (lambda p, d: dict(targets=[[d.targets[:, :8]] + [None] * 3 + [d.targets]]),
     r"targets\[0\] at zoom 4 must have shape"),
    (lambda p, d: dict(targets=[[None] * 4]), "targets must hold 5 zooms a run"),
    (lambda p, d: dict(rates=[1e-4]), "rates must hold one entry per zoom"),
    (lambda p, d: dict(batch_size=33), "batch_size 33 is more than"),
    (lambda p, d: dict(zooms=[5, 3, 2, 1, 0]), "zooms must be integers in 0..4"),
    (lambda p, d: dict(param_index=torch.zeros(d.points.shape[0], 1, dtype=torch.int64) + 3,
                       theta0=torch.zeros(1, 2, 2, dtype=torch.float64)), "param_index must lie in"),
    (lambda p, d: dict(row_rate=torch.ones(1, dtype=torch.float64)), "theta0 must be"),
], ids=["runs", "rows", "order-range", "order-shape", "offsets", "pixels", "bases", "target-shape", "target-zooms",
        "rates", "batch", "zooms", "param-index", "row-rate"])
def test_train_program_refuses_arrays_that_do_not_fit_each_other(program, data, change, named):
    with pytest.raises(SDMInputError, match=f"train_program: {named}"):
        native.train_program(**dict(program, **change(program, data)))


@needs_kernel
def test_the_chain_refuses_a_configuration_beyond_its_tables(data):
    n_points = data.points.shape[0]
    pixels = data.pixels
    config = torch.full((n_points,), 3, dtype=torch.int64)
    scratch = torch.full((2 * (2 * 8 * 8 + 1),), 0, dtype=torch.int64)  # tables of two 8 x 8 configurations
    with pytest.raises(SDMInputError, match=r"chain: config must lie in \[0, 2\)"):
        native.chain(pixels, pixels, config, data.rank, scratch, 8, 8, 2, 0)


@needs_kernel
def test_the_paper_flow_refuses_a_landing_off_the_target(data):
    n_points = 4
    screen = torch.zeros(n_points, 2, dtype=torch.float64)
    config = torch.zeros(n_points, dtype=torch.int64)
    landed = torch.ones(n_points, dtype=torch.bool)
    block = torch.zeros(n_points, 2, dtype=torch.int64)
    landing = torch.tensor([[0, 0], [0, 1], [1, 1], [9, 0]])
    target = torch.zeros(1, 8, 8, dtype=torch.bool)
    refused = (r"paper_flow: every landed point's config must lie in \[0, 1\) \(the targets\), its landing on the "
               r"8 x 8 grid")
    with pytest.raises(SDMInputError, match=refused):
        native.paper_flow(screen, config, landed, block, landing, target, 0)
    with pytest.raises(SDMInputError, match=refused):
        native.paper_flow(screen, config + 1, landed, block, landing.clamp(max=7), target, 0)
    with pytest.raises(SDMInputError, match=refused):  # a landing two blocks from its block
        native.paper_flow(screen, config, landed, block, landing.clamp(max=2), target, 0)


@needs_kernel
def test_the_chain_refuses_start_pixels_whose_moves_would_leave_int64(data):
    pixels = data.pixels.clone()
    pixels[0, 0] = 2**62
    config = torch.zeros(data.points.shape[0], dtype=torch.int64)
    scratch = torch.full((2 * (128 * 256 + 1),), 0, dtype=torch.int64)
    with pytest.raises(SDMInputError, match=r"chain: pixels must lie within"):
        native.chain(data.pixels, pixels, config, data.rank, scratch, 128, 256, 2, 0)

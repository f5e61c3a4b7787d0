"""A property test of the trainer, the refinement and the layer over generated arguments, valid and invalid.

Each generated call either raises :class:`SDMInputError` naming one of its arguments, or returns theta (the layer:
pixels, flow and flags) equal to the bit to the torch path's, and equal again on a second identical call. No crash,
no value read from memory no tensor holds. ``PROPERTY_EXAMPLES`` (the environment) sets the number of generated
cases per test (default below); ``make sanitize`` runs this file under AddressSanitizer.
"""
from __future__ import annotations

import os
from dataclasses import replace

import pytest
import torch
from hypothesis import HealthCheck, event, given, settings, strategies as st

from scenes import configuration_set
from sdm.errors import SDMInputError
from sdm.mapping import SpatialDomainMapping, native
from sdm.train import Refinement, RunsHistory, TrainSettings, refine_runs, train_runs

#: Generated cases per test (each a compiled call, its torch twin and a repeat).
EXAMPLES = int(os.environ.get("PROPERTY_EXAMPLES", "200"))
SETS = {n: configuration_set(n, seed=40 + n) for n in (17, 24)}
#: What an SDMInputError of these calls may name: each message starts with or holds one of them.
ARGUMENTS = ("targets", "settings", "theta0", "param_index", "row_rate", "history", "the training set", "points",
             "pixels", "target", "config", "rank", "screen size", "landing")
PROPERTY = settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _outcome(call):
    """``("error", message)`` for an SDMInputError (any other exception fails the test), else ``("ok", result)``."""
    try:
        result = call()
    except SDMInputError as error:
        event("refused: " + str(error).split(":")[0][:40])
        return "error", str(error)
    event("ran")
    return "ok", result


def _names_an_argument(message: str) -> bool:
    return any(name in message for name in ARGUMENTS)


@st.composite
def runs_arguments(draw):
    """Arguments of train_runs: a set, R target sets, R settings, starts, param_index and row_rate, some wrong."""
    data = SETS[draw(st.sampled_from(sorted(SETS)))]
    n_points, n_configs = data.points.shape[0], len(data)
    s = draw(st.integers(1, 2))
    base = TrainSettings(lr=draw(st.sampled_from([1e-4, 3e-4])), s=s, zoom=draw(st.integers(0, s)),
                         batch_size=draw(st.sampled_from([4, 8, 8, 16, 30])),
                         rule=draw(st.sampled_from(["paper", "closed_centred_r1", "group_crossing"])))
    n_runs = draw(st.integers(1, 3))
    settings_ = [replace(base, seed=draw(st.integers(0, 5))) for _ in range(n_runs)]
    if draw(st.integers(0, 9)) == 0:  # a run that differs beyond its seed
        settings_[-1] = replace(settings_[-1], lr=settings_[-1].lr * 2)
    targets = [data.targets] * n_runs
    wrong_targets = draw(st.sampled_from(["none"] * 8 + ["count", "shape", "dtype"]))
    if wrong_targets == "count":
        targets = targets + [data.targets]
    elif wrong_targets == "shape":
        targets = [data.targets[:-1]] + targets[1:]
    elif wrong_targets == "dtype":
        targets = [data.targets.to(torch.uint8)] + targets[1:]
    index = draw(st.sampled_from(["none", "none", "config", "config", "two", "short", "negative", "hole"]))
    config = torch.repeat_interleave(torch.arange(n_configs), data.counts)
    param_index = {"none": None, "config": config, "two": torch.stack((config % 2, 2 + config % 3), 1),
                   "short": config[:-1], "negative": config - 1, "hole": config * 2}[index]
    n_rows = None if param_index is None else int(param_index.max()) + 1
    start = draw(st.sampled_from(["none", "zero", "zero", "wrong", "nan"]))
    row_shape = (2,) if n_rows is None else (n_rows, 2)
    theta0 = {"none": None, "zero": [torch.zeros(row_shape, dtype=torch.float64)] * n_runs,
              "wrong": [torch.zeros(3, 3, dtype=torch.float64)] * n_runs,
              "nan": [torch.full(row_shape, float("nan"), dtype=torch.float64)] * n_runs}[start]
    rate = draw(st.sampled_from(["none", "none", "ones", "short"]))
    row_rate = {"none": None, "ones": None if n_rows is None else torch.ones(n_rows, dtype=torch.float64),
                "short": torch.ones(1, dtype=torch.float64)}[rate]
    return data, targets, settings_, dict(theta0=theta0, param_index=param_index, row_rate=row_rate)


def _same(one: RunsHistory, other: RunsHistory) -> bool:
    return torch.equal(one.theta, other.theta) and torch.equal(one.theta_steps, other.theta_steps)


@pytest.mark.skipif(not native.enabled(), reason="no C compiler: the compiled kernel is not built")
@PROPERTY
@given(runs_arguments())
def test_train_runs_raises_naming_an_argument_or_equals_the_torch_path(arguments):
    data, targets, settings_, keywords = arguments
    kind, compiled = _outcome(lambda: train_runs(data, targets, settings_, **keywords))
    if kind == "error":
        assert _names_an_argument(compiled), compiled
        return
    assert bool(torch.isfinite(compiled.theta).all())
    assert _same(compiled, train_runs(data, targets, settings_, **keywords))  # a second call: the same bits
    with native.disabled():
        assert _same(compiled, train_runs(data, targets, settings_, **keywords))


@pytest.mark.skipif(not native.enabled(), reason="no C compiler: the compiled kernel is not built")
@PROPERTY
@given(runs_arguments(), st.sampled_from(["same", "same", "without", "with", "fewer"]),
       st.sampled_from(["group_crossing", "closed_centred_r1"]), st.integers(1, 5))
def test_refine_runs_raises_naming_an_argument_or_equals_the_torch_path(arguments, history_of, flow, pass_steps):
    """The refinement of a history trained with the same arguments, or of one trained otherwise: with or without
    param_index, or of fewer runs."""
    data, targets, settings_, keywords = arguments
    trained = dict(keywords)
    if history_of == "without":
        trained.update(param_index=None, row_rate=None, theta0=None)
    elif history_of == "with":
        config = torch.repeat_interleave(torch.arange(len(data)), data.counts)
        trained.update(param_index=config, row_rate=None, theta0=None)
    n_trained = max(len(settings_) - 1, 1) if history_of == "fewer" else len(settings_)
    kind, history = _outcome(lambda: train_runs(data, targets[:n_trained], settings_[:n_trained], **trained))
    if kind == "error":
        return  # train_runs' own property is the test above
    refinement = Refinement(flow, 1, pass_steps=pass_steps)
    refine = dict(param_index=keywords["param_index"], row_rate=keywords["row_rate"])
    kind, compiled = _outcome(lambda: refine_runs(data, targets, settings_, history, refinement, **refine))
    if kind == "error":
        assert _names_an_argument(compiled), compiled
        return
    assert bool(torch.isfinite(compiled.theta).all())
    assert _same(compiled, refine_runs(data, targets, settings_, history, refinement, **refine))
    with native.disabled():
        assert _same(compiled, refine_runs(data, targets, settings_, history, refinement, **refine))


@st.composite
def layer_arguments(draw):
    """Arguments of the layer over a set's first configurations: points, pixels, target, config, rank."""
    data = SETS[17]
    n = draw(st.integers(1, 4))
    end = int(data.offsets[n])
    points, pixels = data.points[:end].clone(), data.pixels[:end].clone()
    config = torch.repeat_interleave(torch.arange(n), data.counts[:n])
    target = data.targets[:n]
    shift = draw(st.floats(-2.0, 2.0, allow_nan=False))
    points[:, 0] += shift
    wrong = draw(st.sampled_from(["none"] * 6 + ["config", "pixels", "target", "rank", "points"]))
    rank = None
    if wrong == "config":
        config = config + n
    elif wrong == "pixels":
        pixels = pixels[:-1]
    elif wrong == "target":
        target = target[:, :-1]
    elif wrong == "rank":
        rank = torch.zeros(end + 1, dtype=torch.int64)
    elif wrong == "points":
        points[0, 2] = float("nan")
    s = draw(st.integers(0, 3))
    return dict(s=s, zoom=draw(st.integers(0, s)), rule=draw(st.sampled_from(["paper", "closed_centred_r1"])),
                validate=draw(st.booleans())), (points, pixels, target, config, rank)


def _mapped(layer_keywords, tensors):
    points, pixels, target, config, rank = tensors
    layer = SpatialDomainMapping(s=layer_keywords["s"], zoom=layer_keywords["zoom"], rule=layer_keywords["rule"])
    points = points.clone().requires_grad_(True)
    out = layer(points, pixels, target, config, rank, validate=layer_keywords["validate"])
    out.loss.backward()
    result = out.result
    return [result.out_pixels, result.entered, result.matched, result.landed, result.flow, points.grad]


@pytest.mark.skipif(not native.enabled(), reason="no C compiler: the compiled kernel is not built")
@PROPERTY
@given(layer_arguments())
def test_the_layer_raises_naming_an_argument_or_equals_the_torch_path(arguments):
    layer_keywords, tensors = arguments
    kind, compiled = _outcome(lambda: _mapped(layer_keywords, tensors))
    if kind == "error":
        assert _names_an_argument(compiled), compiled
        return
    again = _mapped(layer_keywords, tensors)
    assert all(torch.equal(one, other) for one, other in zip(compiled, again))
    checked = _outcome(lambda: _mapped(dict(layer_keywords, validate=True), tensors))[0] == "ok"
    if layer_keywords["validate"] or checked:  # the torch path of an unchecked bad input computes no defined result
        with native.disabled():
            reference = _mapped(layer_keywords, tensors)
        assert all(torch.equal(one, other) for one, other in zip(compiled, reference))

"""The alternative gradient rules (issue 12): registry, fixed point at theta*, bias under noise."""
from __future__ import annotations

import pytest
import torch

from scenes import configurations
from sdm import FLOW_RULES, TrainSettings
from sdm.batch import ConfigurationSet
from sdm.camera import APOLLO_CAMERA_5
from sdm.errors import SDMInputError
from sdm.mapping import SpatialDomainMapping, dynamic_flow
from sdm.mapping.fast import fast_mapping
from sdm.mapping.rules import _rule
from sdm.sky import SKY_SHIFT, add_target_noise, shift_vector
from sdm.zoom import zoom_out

CAM = APOLLO_CAMERA_5


@pytest.fixture(scope="module")
def batch():
    return ConfigurationSet.from_configurations(configurations(12, 5)).batch(range(12))


def _map(batch, theta, target, zoom, rule):
    points = batch.points + shift_vector(theta, batch.points)
    return fast_mapping(points, batch.pixels, batch.config, batch.rank, zoom_out(target, zoom), 4, zoom, CAM,
                        flow_rule=rule)


def test_paper_is_the_default_and_unknown_names_are_refused():
    assert FLOW_RULES["paper"] is dynamic_flow
    assert TrainSettings().flow == "paper"
    assert SpatialDomainMapping().flow_rule is dynamic_flow
    with pytest.raises(SDMInputError, match="flow"):
        TrainSettings(flow="no-such-rule")
    with pytest.raises(SDMInputError, match="flow"):
        SpatialDomainMapping(flow="no-such-rule")
    with pytest.raises(SDMInputError, match="flow"):
        SpatialDomainMapping(method="dense", flow="nearest")


@pytest.mark.parametrize("zoom", [0, 2])
def test_the_generic_window_reproduces_the_paper(batch, zoom):
    """The rule builder with no hooks is eq. 19: its flow equals dynamic_flow's off theta* (an independent window)."""
    for theta in ((0.3, 0.1), (0.7, 0.45)):
        paper = _map(batch, theta, batch.targets, zoom, dynamic_flow)
        generic = _map(batch, theta, batch.targets, zoom, _rule())
        assert bool(paper.flow.any())  # not vacuous: points are pulled here
        assert torch.equal(paper.flow, generic.flow) and torch.equal(paper.matched, generic.matched)
        assert float(generic.loss) == pytest.approx(float(paper.loss), rel=1e-12)


@pytest.mark.parametrize("name", sorted(FLOW_RULES))
def test_true_shift_is_an_exact_fixed_point_without_noise(batch, name):
    for zoom in (4, 3, 2, 1, 0):
        result = _map(batch, SKY_SHIFT, batch.targets, zoom, FLOW_RULES[name])
        assert float(result.loss) == 0 and not bool(result.flow.any()), (name, zoom)
    # ... and it is not a fixed point elsewhere: the rule pulls towards theta*.
    result = _map(batch, (SKY_SHIFT[0] - 0.3, SKY_SHIFT[1] - 0.2), batch.targets, 0, FLOW_RULES[name])
    assert float(result.flow[:, 0].sum()) < 0 and float(result.flow[:, 1].sum()) < 0, name


@pytest.mark.parametrize("name,bound", [("nearest", 1.0), ("normalised", 1.0)])
def test_bounded_rules_pull_each_point_at_most_once_per_axis(batch, name, bound):
    result = _map(batch, (0.2, 0.1), batch.targets, 0, FLOW_RULES[name])
    assert bool(result.flow.any()) and float(result.flow.abs().max()) <= bound

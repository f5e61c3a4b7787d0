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


def _mean_flow_at_true_shift(batch, level, rule, draws):
    """``(draws, 2)`` summed flow per configuration at theta*, zoom 0, one noise draw per row (seeds 100 * level + d)."""
    points = batch.points + shift_vector(SKY_SHIFT, batch.points)
    n_configs = int(batch.targets.shape[0])
    flows = []
    for draw in range(draws):
        noisy = add_target_noise(batch.targets, level, torch.Generator().manual_seed(100 * level + draw))
        result = fast_mapping(points, batch.pixels, batch.config, batch.rank, noisy, 4, 0, CAM, flow_rule=rule)
        flows.append(result.flow.sum(0) / n_configs)
    return torch.stack(flows)


@pytest.mark.parametrize("name", ["closed", "closed5", "closed_r1", "closed_centred_r1"])
@pytest.mark.parametrize("level", [2, 4])
def test_closing_the_target_removes_most_of_the_bias_at_the_true_shift(batch, name, level):
    """No rule here is exactly unbiased (measured: docs/method.md, "Beyond the paper"); the closed ones cut the
    paper's pull at theta* under noise to a small fraction.

    On the same draws the paper's mean y pull is about -80 per configuration (the bias SGD follows), with a
    standard error near 1; the closed rules' is below 15 in magnitude (3 to 14 measured on 32 scenes, 40
    draws). The bound, a quarter of the paper's own mean on the same draws, sits well clear of both
    (the standard errors over 12 draws are about 1 to 2).
    """
    paper = _mean_flow_at_true_shift(batch, level, FLOW_RULES["paper"], 12).mean(0)
    rule = _mean_flow_at_true_shift(batch, level, FLOW_RULES[name], 12).mean(0)
    assert float(paper[1]) < -20  # the bias is there to remove
    assert abs(float(rule[1])) < abs(float(paper[1])) / 4
    assert abs(float(rule[0])) < max(abs(float(paper[0])), 5.0)


def test_a_named_rule_reaches_training_alone_and_in_packed_runs():
    """TrainSettings(flow=...) is honoured by train and train_runs alike (same history), and changes the training."""
    from sdm import train, train_runs

    data = ConfigurationSet.from_configurations(configurations(32, 9))
    noisy = add_target_noise(data.targets, 2, torch.Generator().manual_seed(3))
    settings = TrainSettings(lr=1e-4, n_epoch=1, s=2, seed=4, flow="closed")
    alone = train(data.with_targets(noisy), settings, progress=False)
    packed = train_runs(data, [noisy], [settings])
    assert torch.equal(alone.theta, packed.theta[:, 0])
    paper = train(data.with_targets(noisy), TrainSettings(lr=1e-4, n_epoch=1, s=2, seed=4), progress=False)
    assert not torch.equal(alone.theta, paper.theta)


@pytest.mark.parametrize("name,fine", [("closed_r1", "closed"), ("closed_centred_r1", "closed_centred")])
def test_zoom_scheduled_rules_are_the_paper_coarse_and_closed_at_full_resolution(batch, name, fine):
    """closed_r1 and closed_centred_r1 pull exactly as eq. 19 at zoom >= 1 and as their closed rule at zoom 0.

    Checked on noisy targets off theta*, where every rule pulls (so the equalities are not vacuous), and
    the closed rule differs from the paper's at zoom 0 (so the switch is not a no-op).
    """
    noisy = add_target_noise(batch.targets, 3, torch.Generator().manual_seed(7))
    theta = (SKY_SHIFT[0] - 0.05, SKY_SHIFT[1] + 0.03)
    for zoom in (3, 2, 1):
        paper = _map(batch, theta, noisy, zoom, dynamic_flow)
        scheduled = _map(batch, theta, noisy, zoom, FLOW_RULES[name])
        assert bool(paper.flow.any()) and torch.equal(paper.flow, scheduled.flow), zoom
    closed = _map(batch, theta, noisy, 0, FLOW_RULES[fine])
    scheduled = _map(batch, theta, noisy, 0, FLOW_RULES[name])
    assert torch.equal(closed.flow, scheduled.flow) and float(closed.loss) == float(scheduled.loss)
    assert not torch.equal(closed.flow, _map(batch, theta, noisy, 0, dynamic_flow).flow)


def test_a_centred_window_is_centred_on_the_landing_block():
    """One point whose kernel stepped it one column right: the paper's window (around its input block) sees a
    target block two columns left of where it landed; the centred window (around the landing block) does not,
    and sees one a column right of it that the paper's window cannot."""
    from sdm.mapping.rules import _rule

    screen = torch.tensor([[5.5, 11.5]], dtype=torch.float64)  # landed in pixel (5, 11)
    depth = torch.tensor([20.0], dtype=torch.float64)
    config = torch.zeros(1, dtype=torch.int64)
    landed = torch.ones(1, dtype=torch.bool)
    block, landing = torch.tensor([[5, 10]]), torch.tensor([[5, 11]])
    for target_column, paper_pulls, centred_pulls in ((9, True, False), (12, False, True)):
        target = torch.zeros(1, *CAM.screen_shape, dtype=torch.bool)
        target[0, 5, target_column] = True
        paper = dynamic_flow(screen, depth, config, landed, block, landing, target, 0, CAM)[0]
        centred = _rule(centred=True)(screen, depth, config, landed, block, landing, target, 0, CAM)[0]
        assert bool(paper.any()) == paper_pulls and bool(centred.any()) == centred_pulls, target_column
        if centred_pulls:  # towards the target on the right: dJ/dx < 0
            assert float(centred[0, 0]) == -1.0


def test_the_two_sided_rule_pulls_a_matched_point_towards_an_uncovered_target_block():
    """The reverse side: a target block next to a matched point that no projection covers pulls the point;
    the one-sided rules leave a matched point alone."""
    screen = torch.tensor([[5.5, 11.5]], dtype=torch.float64)
    depth = torch.tensor([20.0], dtype=torch.float64)
    config = torch.zeros(1, dtype=torch.int64)
    landed = torch.ones(1, dtype=torch.bool)
    block = landing = torch.tensor([[5, 11]])
    target = torch.zeros(1, *CAM.screen_shape, dtype=torch.bool)
    target[0, 5, 11] = target[0, 6, 11] = True  # its own pixel (matched) and one below it, uncovered
    flow, loss, matched = FLOW_RULES["two_sided"](screen, depth, config, landed, block, landing, target, 0, CAM)
    assert bool(matched[0]) and flow[0].tolist() == [0.0, -1.0] and float(loss) > 0
    assert not bool(FLOW_RULES["paper"](screen, depth, config, landed, block, landing, target, 0, CAM)[0].any())

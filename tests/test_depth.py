"""Depth: the depth flow on single points (as Fig. 3 for x and y), targets and training of (a, b, c)."""
from __future__ import annotations

import pytest
import torch

from scenes import configurations
from sdm import TrainSettings, train
from sdm.batch import ConfigurationSet
from sdm.camera import APOLLO_CAMERA_5
from sdm.depth import depth_flow, depth_targets
from sdm.mapping import SpatialDomainMapping
from train_reference import reference_train

CAM = APOLLO_CAMERA_5


def _z_gradient(pixel, target_step, depth=20.0):
    """dJ/dz of one point at the centre of ``pixel`` whose only target pixel is ``pixel + target_step``."""
    screen = torch.tensor([[pixel[0] + 0.5, pixel[1] + 0.5]], dtype=torch.float64)
    points = CAM.backproject(screen, torch.tensor([depth], dtype=torch.float64)).requires_grad_(True)
    target = torch.zeros(CAM.screen_shape, dtype=torch.bool)
    target[pixel[0] + target_step[0], pixel[1] + target_step[1]] = True
    out = SpatialDomainMapping(CAM, s=0, zoom=0, fit_depth=True)(points, torch.tensor([list(pixel)]), target)
    out.loss.backward()
    assert float(out.loss.detach()) > 0  # the point is pulled
    return float(points.grad[0, 2])


def _principal_point():
    return CAM.project(torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64))[0].tolist()  # (row, col)


@pytest.mark.parametrize("side", [-1, 1])
def test_a_target_radially_outside_pulls_the_point_nearer(side):
    """Right of the principal point a target one column further right needs a larger |u - c_x|: z must shrink."""
    row0, col0 = (int(v) for v in _principal_point())
    pixel = (min(max(row0, 1), CAM.screen_shape[0] - 2), col0 + side * 40)
    assert _z_gradient(pixel, (0, side)) > 0  # SGD lowers z
    assert _z_gradient(pixel, (0, -side)) < 0  # inside: SGD raises z


def test_depth_flow_vanishes_on_the_optical_axis_and_has_the_derived_form():
    points = torch.tensor([[0.0, 0.0, 10.0], [2.0, -1.0, 10.0]], dtype=torch.float64)
    flow = torch.tensor([[1.0, -1.0], [1.0, 2.0]], dtype=torch.float64)
    assert depth_flow(points, flow).tolist() == [0.0, -(2.0 * 1.0 + (-1.0) * 2.0) / 10.0]


def test_depth_targets_are_the_points_moved_in_depth():
    """depth_targets with c = 0 gives build_configuration's own targets; with c it is floor(P(Q + (a, b, c)))."""
    data = ConfigurationSet.from_configurations(configurations(3, 2))
    assert torch.equal(depth_targets(data, (0.517, 0.303, 0.0)), data.targets)
    deep = depth_targets(data, (0.517, 0.303, 1.0))
    assert not torch.equal(deep, data.targets)
    moved = data.points + torch.tensor([0.517, 0.303, 1.0], dtype=torch.float64)
    pixels = data.camera.project(moved).floor().long()
    config = torch.repeat_interleave(torch.arange(len(data)), data.counts)
    height, width = data.camera.screen_shape
    on = (pixels[:, 0] >= 0) & (pixels[:, 0] < height) & (pixels[:, 1] >= 0) & (pixels[:, 1] < width)
    reference = torch.zeros_like(data.targets)
    reference[config[on], pixels[on, 0], pixels[on, 1]] = True
    assert torch.equal(deep, reference)



def test_training_recovers_a_depth_shift():
    data = ConfigurationSet.from_configurations(configurations(128, 4))
    truth = (0.517, 0.303, 1.0)
    data = data.with_targets(depth_targets(data, truth))
    history = train(data, TrainSettings(lr=1e-4, n_epoch=4, s=4, fit_depth=True), progress=False)
    a, b, c = history.final_theta
    assert abs(a - truth[0]) < 5e-3 and abs(b - truth[1]) < 5e-3 and abs(c - truth[2]) < 5e-2


def test_depth_runs_trained_together_follow_their_own_histories():
    """train_runs(fit_depth=True): each run's (a, b, c) history equals train() alone for its seed and targets.

    The depth flow is a float sum (not a sum of integer signs), so the packed runs may round it differently:
    held to 1e-12 m at every step. Two runs with different depths, noise and shuffling, so a run that took
    another run's flow would be caught.
    """
    from sdm import train_runs
    from sdm.sky import add_target_noise

    data = ConfigurationSet.from_configurations(configurations(48, 6))
    targets = [add_target_noise(depth_targets(data, (0.517, 0.303, depth)), level, torch.Generator().manual_seed(seed))
               for depth, level, seed in ((1.0, 0, 1), (-0.5, 2, 2))]
    settings = [TrainSettings(lr=1e-4, n_epoch=1, s=3, seed=seed, fit_depth=True, rule="closed") for seed in (5, 6)]
    packed = train_runs(data, targets, settings)
    assert packed.theta.shape[1:] == (2, 3)
    for run, (run_targets, run_settings) in enumerate(zip(targets, settings)):
        alone = train(data.with_targets(run_targets), run_settings, progress=False)
        reference, _ = reference_train(data.with_targets(run_targets), run_settings)
        assert torch.equal(alone.theta, reference), run  # one run: the reference's sums, to the bit
        assert alone.theta.shape == packed.theta[:, run].shape
        assert float((reference - packed.theta[:, run]).abs().max()) <= 1e-12, run
        assert abs(alone.final_theta[2]) > 0.1  # c moved: the depth flow reached it
    assert abs(packed.final_theta[0][2] - packed.final_theta[1][2]) > 0.1  # each run its own c


def test_depth_zoom_holds_c_at_the_finer_zooms():
    """c moves down to depth_zoom and is held below it, while (a, b) go on; depth_zoom beyond s means s."""
    data = ConfigurationSet.from_configurations(configurations(48, 6))
    data = data.with_targets(depth_targets(data, (0.517, 0.303, 1.0)))
    for depth_zoom, held_zooms in ((1, [0]), (2, [1, 0]), (9, [2, 1, 0])):
        history = train(data, TrainSettings(lr=1e-4, n_epoch=1, s=3, fit_depth=True, depth_zoom=depth_zoom),
                        progress=False)
        moved = (history.theta[1:] != history.theta[:-1])  # (steps, 3) this step changed the parameter
        for zoom in range(3, -1, -1):
            at_zoom = history.zoom == zoom
            assert bool(moved[at_zoom, 0].any() or moved[at_zoom, 1].any()), (depth_zoom, zoom)
            assert bool(moved[at_zoom, 2].any()) == (zoom not in held_zooms), (depth_zoom, zoom)
    with pytest.raises(Exception, match="depth_zoom"):
        TrainSettings(fit_depth=True, depth_zoom=-1)

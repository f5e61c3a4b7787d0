"""2D Chamfer distance between the projected shifted points and the target's active pixel centres.

For one configuration, with ``A`` the points ``P(Q + (a, b, 0))`` that land on the screen and ``T``
the centres ``(row + 0.5, col + 0.5)`` of the target's active pixels (screen pixels)::

    chamfer(A, T) = mean_{x in A} min_{y in T} |x - y|^2  +  mean_{y in T} min_{x in A} |x - y|^2

both directions, squared distances (the usual point-cloud Chamfer loss), nearest neighbours found
with ``torch.cdist`` on zero-padded batches with the padding masked out; the loss of a step is the mean
over the mini-batch's configurations that have both points and target pixels.

Subsampling: when ``max_points > 0`` each step draws up to ``max_points`` points and as many
target pixels per configuration (uniformly, from the run's seed). The point-to-target term stays
an unbiased estimate of its full value; the target-to-point term grows a little (nearest
neighbours among fewer points are farther) but symmetrically around theta*, so the minimiser does
not move; a cheaper step lets more steps fit the time budget.

Off-screen points are left out at every step (their pixels were dropped from the target too), and
at theta* every point sits inside its target pixel, at most half a pixel from its centre: the loss
there is not zero but its gradient averages out over the many sub-pixel offsets.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from ..batch import ConfigurationSet
from ..camera import Camera
from .common import FitResult, check_positive, check_positive_int, pad_set, sampled_pair, staged_adam, timed


@dataclass(frozen=True)
class ChamferSettings:
    """Hyper-parameters of the Chamfer fit.

    Attributes:
        lr: Adam's learning rate in the first round, metres.
        steps: Adam steps per round.
        rounds: rounds; the learning rate is multiplied by ``lr_decay`` after each.
        lr_decay: learning-rate factor per round.
        batch_size: configurations per step.
        max_points: points (and target pixels) drawn per configuration and step; 0 = all.
    """

    lr: float = 0.3
    steps: int = 48
    rounds: int = 5
    lr_decay: float = 0.5
    batch_size: int = 16
    max_points: int = 128

    def __post_init__(self) -> None:
        check_positive(self, ("lr", "lr_decay"))
        check_positive_int(self, ("steps", "rounds", "batch_size"))
        check_positive_int(self, ("max_points",), allow_zero=("max_points",))


def chamfer_2d(points: torch.Tensor, point_mask: torch.Tensor, centres: torch.Tensor,
               centre_mask: torch.Tensor) -> torch.Tensor:
    """Per-configuration two-way Chamfer distance of padded 2D point sets.

    The nearest neighbours are found without autograd (``torch.cdist`` in float32, the search
    only); the squared distances to them are then recomputed in the inputs' dtype with autograd.
    Value and gradient are those of the plain ``min`` formulation (its gradient also flows only
    through the arg-min pairs), at a fraction of the memory and time.

    Args:
        points: ``(B, P, 2)`` float screen positions (may require grad).
        point_mask: ``(B, P)`` bool, real points.
        centres: ``(B, T, 2)`` float target positions, same dtype.
        centre_mask: ``(B, T)`` bool, real target pixels.

    Returns:
        ``(B,)`` squared screen pixels; NaN for a configuration with no point or no target pixel.
    """
    with torch.no_grad():
        squared = torch.cdist(points.detach().float(), centres.float())  # (B, P, T); monotone in the distance
        blocked = ~(point_mask.unsqueeze(2) & centre_mask.unsqueeze(1))
        squared.masked_fill_(blocked, float("inf"))
        nearest_centre = squared.argmin(dim=2)  # (B, P)
        nearest_point = squared.argmin(dim=1)  # (B, T)
    to_target = ((points - centres.gather(1, nearest_centre.unsqueeze(-1).expand(-1, -1, 2))) ** 2).sum(-1)
    to_points = ((points.gather(1, nearest_point.unsqueeze(-1).expand(-1, -1, 2)) - centres) ** 2).sum(-1)
    forward = torch.where(point_mask, to_target, torch.zeros_like(to_target)).sum(1) / point_mask.sum(1)
    backward = torch.where(centre_mask, to_points, torch.zeros_like(to_points)).sum(1) / centre_mask.sum(1)
    return forward + backward


def fit(train_set: ConfigurationSet, settings: ChamferSettings = ChamferSettings(), seed: int = 0,
        camera: Camera | None = None, theta0=(0.0, 0.0)) -> FitResult:
    """Estimate ``theta`` by Adam on the 2D Chamfer distance.

    Returns:
        :class:`~sdm.baselines.common.FitResult`; history stages are the rounds ``rounds-1..0``.
    """
    camera = camera or train_set.camera

    def run() -> FitResult:
        padded = pad_set(train_set)

        def loss(configs, theta, stage, generator):
            screen, kept, centres, target_kept = sampled_pair(padded, configs, theta, camera, settings.max_points,
                                                              generator)
            value = chamfer_2d(screen, kept, centres, target_kept)
            usable = torch.isfinite(value)
            if not bool(usable.any()):  # nothing to match in this batch: a zero loss with a zero gradient
                return theta.sum() * 0.0
            return value[usable].mean()

        return staged_adam(loss, len(train_set), range(settings.rounds - 1, -1, -1), settings.steps, settings.lr,
                           settings.lr_decay, settings.batch_size, seed, theta0, device=train_set.points.device)

    return timed(run)

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
from typing import Sequence

import torch

from ...batch import ConfigurationSet
from ...camera import Camera
from .common import (
    FitResult, check_positive, check_positive_int, check_runs, mean_of_usable, pack_run_targets, pad_points,
    sampled_pairs, staged_adam_runs, timed_runs,
)


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


#: Configurations whose nearest neighbours :func:`fit_runs` searches in one ``cdist``: four runs'
#: mini-batches of 16. The search is arithmetic on ``(n, 128, 128)`` matrices, so batching shares
#: little on a CPU; measured on one thread (default data, 20 runs), 64 was a little faster than one
#: run's 16 or all 320 at once (those leave the cache), within the noise of a shared machine.
#: Each configuration's search is its own whatever the grouping: results do not depend on it.
CONFIGS_PER_SEARCH = 64

#: Where padding is parked for the nearest-neighbour search, screen pixels: far beyond any screen
#: (distances stay far below float32's range).
FAR = 1.0e5


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
        # Padding is parked far off screen (points at -FAR, centres at +FAR) instead of masking the
        # (B, P, T) matrix with inf: the same arg-mins for every real point and real centre (a real
        # pair is never farther than the screen's diagonal; each distance is computed from its own
        # pair only), the same index 0 where a row has no real partner (all equal, first wins), and
        # the two (B, P, T) mask passes saved. Padding rows' arg-mins differ but are masked below.
        search_points = torch.where(point_mask.unsqueeze(-1), points.detach(), -FAR).float()
        search_centres = torch.where(centre_mask.unsqueeze(-1), centres, FAR).float()
        squared = torch.cdist(search_points, search_centres)  # (B, P, T); monotone in the distance
        # min(dim).indices, not argmin: the same first index of the minimum, and across dim 1 (a strided
        # reduction) twice as fast on the CPU (one thread, (64, 128, 128) float32: 1.3 against 2.6 ms)
        nearest_centre = squared.min(dim=2).indices  # (B, P)
        nearest_point = squared.min(dim=1).indices  # (B, T)
    to_target = ((points - centres.gather(1, nearest_centre.unsqueeze(-1).expand(-1, -1, 2))) ** 2).sum(-1)
    to_points = ((points.gather(1, nearest_point.unsqueeze(-1).expand(-1, -1, 2)) - centres) ** 2).sum(-1)
    forward = torch.where(point_mask, to_target, torch.zeros_like(to_target)).sum(1) / point_mask.sum(1)
    backward = torch.where(centre_mask, to_points, torch.zeros_like(to_points)).sum(1) / centre_mask.sum(1)
    return forward + backward


def fit(train_set: ConfigurationSet, settings: ChamferSettings = ChamferSettings(), seed: int = 0,
        camera: Camera | None = None, theta0=(0.0, 0.0)) -> FitResult:
    """Estimate ``theta`` by Adam on the 2D Chamfer distance: one run of :func:`fit_runs`.

    Returns:
        :class:`~sdm.experiments.baselines.common.FitResult`; history stages are the rounds ``rounds-1..0``.
    """
    return fit_runs([train_set], settings, [seed], camera, theta0)[0]


def fit_runs(train_sets: Sequence[ConfigurationSet], settings: ChamferSettings = ChamferSettings(),
             seeds: Sequence[int] = (0,), camera: Camera | None = None, theta0=(0.0, 0.0)) -> list[FitResult]:
    """``R`` independent Chamfer fits as one program: run ``r`` is ``fit(train_sets[r], settings, seeds[r])``.

    Each step stacks the runs' mini-batches into one ``(R x batch_size)``-configuration batch (one
    ``cdist``, one backward), which shares the per-operation overhead of the steps (on one CPU core
    only 1.4x per run: the nearest-neighbour arithmetic dominates, ``benchmarks/speed/bench_baselines.py``); each run keeps its own theta, Adam state and generator (:func:`staged_adam_runs`).

    Args:
        train_sets: ``R`` sets with the same points, offsets and camera (tensors on one device),
            differing only in their targets (e.g. each run's noisy targets).
        settings: shared by every run.
        seeds: ``R`` seeds; ``seeds[r]`` draws run ``r``'s mini-batches and subsamples as ``fit`` does.
        camera: default the sets' camera.
        theta0: every run's start ``(a, b)``, metres.

    Returns:
        One :class:`~sdm.experiments.baselines.common.FitResult` per run; ``seconds`` is the batched fit's wall
        time divided by ``R`` (its cost per run).
    """
    check_runs(train_sets, seeds)
    camera = camera or train_sets[0].camera

    def run() -> list[FitResult]:
        points, point_mask = pad_points(train_sets[0])
        targets = pack_run_targets([train_set.targets for train_set in train_sets])

        def loss(configs, theta, stage, generators):
            screen, kept, centres, target_kept = sampled_pairs(points, point_mask, targets, configs, theta, camera,
                                                               settings.max_points, generators)
            screen, kept, centres, target_kept = (t.flatten(0, 1) for t in (screen, kept, centres, target_kept))
            # A few runs' nearest-neighbour searches at a time (see CONFIGS_PER_SEARCH).
            value = torch.cat([
                chamfer_2d(screen[part], kept[part], centres[part], target_kept[part])
                for part in torch.arange(screen.shape[0], device=screen.device).split(CONFIGS_PER_SEARCH)
            ])
            return mean_of_usable(value.view(configs.shape), theta)

        return staged_adam_runs(loss, len(train_sets[0]), range(settings.rounds - 1, -1, -1), settings.steps,
                                settings.lr, settings.lr_decay, settings.batch_size, seeds, theta0,
                                device=train_sets[0].points.device)

    return timed_runs(run)

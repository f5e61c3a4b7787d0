"""Optimal transport: the Sinkhorn divergence between the projected shifted points and the target pixels.

The same two 2D point sets per configuration as the Chamfer baseline (on-screen projections of
``Q + (a, b, 0)``; centres of the target's active pixels, screen pixels), each given uniform mass,
compared with geomloss's debiased Sinkhorn divergence ``SamplesLoss("sinkhorn", p=2, blur=...)``
(entropic OT with squared Euclidean cost; ``blur`` is the entropic length scale in screen pixels).
Balanced OT matches *all* the mass, so unlike Chamfer it cannot ignore a cluster of points; where
several points land in one pixel the target has fewer pixels than there are points, which uniform
masses tolerate (both sides are normalised to 1).

Coarse to fine: round ``k`` (``rounds - 1`` down to 0) uses ``blur 2^k``, so early rounds see
blurred, far-reaching couplings and the last one is sharp; the learning rate is multiplied by
``lr_decay`` per round.

Cost control: geomloss's ``tensorized`` backend forms the ``(B, N, M)`` cost matrix, and the
epsilon-scaling loop solves three OT problems (the debiasing terms) per step, so each step draws
``max_points`` points and as many target pixels per configuration (uniform, from the run's seed):
OT between random subsamples estimates OT between the full sets, without bias in where its
minimum lies. Padding carries zero mass.

``geomloss`` is imported when a fit starts: it is a dependency of the workflow's baseline stage,
not of the ``sdm`` library.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch

from ...batch import ConfigurationSet
from ...camera import Camera
from .common import (
    FitResult, check_positive, check_positive_int, check_runs, field_error, mean_of_usable, pack_run_targets,
    pad_points, sampled_pairs, staged_adam_runs, timed_runs,
)


@dataclass(frozen=True)
class SinkhornSettings:
    """Hyper-parameters of the Sinkhorn fit.

    Attributes:
        lr: Adam's learning rate in the first round, metres.
        steps: Adam steps per round.
        blur: entropic blur of the last round, screen pixels (``blur 2^k`` in round ``k``).
        rounds: rounds, coarse to fine.
        lr_decay: learning-rate factor per round.
        batch_size: configurations per step.
        max_points: points (and target pixels) drawn per configuration and step; 0 = all.
        scaling: geomloss's epsilon-scaling ratio (0.5: fast; closer to 1: more accurate).
        float32: solve the OT problems in float32 (about half the time; theta and the projection
            stay float64, and the positions are at most a few hundred pixels, so float32 resolves
            1e-5 pixel).
    """

    lr: float = 0.1
    steps: int = 24
    blur: float = 1.0
    rounds: int = 5
    lr_decay: float = 0.5
    batch_size: int = 16
    max_points: int = 64
    scaling: float = 0.5
    float32: bool = True

    def __post_init__(self) -> None:
        check_positive(self, ("lr", "blur", "lr_decay", "scaling"))
        check_positive_int(self, ("steps", "rounds", "batch_size"))
        check_positive_int(self, ("max_points",), allow_zero=("max_points",))
        if not self.scaling < 1:
            raise field_error(self, "scaling", f"must lie in (0, 1), got {self.scaling!r}")


#: OT problems (configurations) solved together in one geomloss call of :func:`fit_runs`: four
#: runs' mini-batches of 16. Every problem is solved on its own whatever the grouping (geomloss's
#: batch axis never mixes), so this only trades per-call overhead against the ``(n, 64, 64)``
#: cost and kernel matrices leaving the cache; on one thread the measured difference between 16,
#: 64 and all problems of 20 runs per call was within the noise of a shared machine.
OT_PROBLEMS_PER_SOLVE = 64


def uniform_weights(mask: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """``(B, N)`` masses: ``1 / count`` on real entries, 0 on padding (a row with none stays 0)."""
    weights = mask.to(dtype)
    return weights / weights.sum(1, keepdim=True).clamp(min=1.0)


def fit(train_set: ConfigurationSet, settings: SinkhornSettings = SinkhornSettings(), seed: int = 0,
        camera: Camera | None = None, theta0=(0.0, 0.0)) -> FitResult:
    """Estimate ``theta`` by Adam on the Sinkhorn divergence, blur annealed coarse to fine: one run of :func:`fit_runs`.

    Returns:
        :class:`~sdm.experiments.baselines.common.FitResult`; history stages are the rounds ``rounds-1..0``.
    """
    return fit_runs([train_set], settings, [seed], camera, theta0)[0]


def fit_runs(train_sets: Sequence[ConfigurationSet], settings: SinkhornSettings = SinkhornSettings(),
             seeds: Sequence[int] = (0,), camera: Camera | None = None, theta0=(0.0, 0.0)) -> list[FitResult]:
    """``R`` independent Sinkhorn fits as one program: run ``r`` is ``fit(train_sets[r], settings, seeds[r])``.

    Each step solves the OT problems of all runs' mini-batches as one geomloss batch of
    ``R x batch_size`` problems (each problem is solved on its own: geomloss's batch axis never
    mixes), which shares the per-operation overhead of the epsilon-scaling loop (on one CPU
    core 1.2x per run: geomloss's log-sum-exp dominates, ``benchmarks/speed/bench_baselines.py``); each run keeps its
    own theta, Adam state and generator (:func:`~sdm.experiments.baselines.common.staged_adam_runs`).

    Args:
        train_sets: ``R`` sets with the same points, offsets and camera (tensors on one device),
            differing only in their targets.
        settings: shared by every run.
        seeds: ``R`` seeds; ``seeds[r]`` draws run ``r``'s mini-batches and subsamples as ``fit`` does.
        camera: default the sets' camera.
        theta0: every run's start ``(a, b)``, metres.

    Returns:
        One :class:`~sdm.experiments.baselines.common.FitResult` per run; ``seconds`` is the batched fit's wall
        time divided by ``R`` (its cost per run).
    """
    from geomloss import SamplesLoss

    check_runs(train_sets, seeds)
    camera = camera or train_sets[0].camera
    height, width = camera.screen_shape
    diameter = float((height**2 + width**2) ** 0.5)  # the largest cost scale on screen: no need to measure it
    losses = {
        stage: SamplesLoss("sinkhorn", p=2, blur=settings.blur * 2.0**stage, scaling=settings.scaling,
                           diameter=diameter, backend="tensorized")
        for stage in range(settings.rounds)
    }

    def run() -> list[FitResult]:
        points, point_mask = pad_points(train_sets[0])
        targets = pack_run_targets([train_set.targets for train_set in train_sets])

        def loss(configs, theta, stage, generators):
            screen, kept, centres, target_kept = sampled_pairs(points, point_mask, targets, configs, theta, camera,
                                                               settings.max_points, generators)
            screen, kept, centres, target_kept = (t.flatten(0, 1) for t in (screen, kept, centres, target_kept))
            usable = kept.any(1) & target_kept.any(1)  # (R * B,)
            dtype = torch.float32 if settings.float32 else screen.dtype
            value = torch.full(usable.shape, float("nan"), dtype=dtype, device=screen.device)
            if bool(usable.any()):
                # Padding (and off-screen points) get zero mass; their positions are pinned to a constant so
                # that no gradient flows through them.
                screen = torch.where(kept.unsqueeze(-1), screen, torch.zeros_like(screen))
                rows = usable.nonzero().squeeze(1)
                # A few runs' problems per solve (see OT_PROBLEMS_PER_SOLVE).
                solved = torch.cat([
                    losses[stage](
                        uniform_weights(kept[part], dtype), screen[part].to(dtype),
                        uniform_weights(target_kept[part], dtype), centres[part].to(dtype),
                    )
                    for part in rows.split(OT_PROBLEMS_PER_SOLVE)
                ])
                value = value.masked_scatter(usable, solved)
            # a run with nothing to transport in its batch: a zero loss with a zero gradient
            return mean_of_usable(value.view(configs.shape), theta)

        return staged_adam_runs(loss, len(train_sets[0]), range(settings.rounds - 1, -1, -1), settings.steps,
                                settings.lr, settings.lr_decay, settings.batch_size, seeds, theta0,
                                device=train_sets[0].points.device)

    return timed_runs(run)

"""SDM itself, as in Table 2: SGD through the SDM layer with the tuned settings (:func:`sdm.train`).

Kept behind the same ``fit(train_set, settings, seed)`` interface as the baselines so that Table 3
compares like with like. ``seed`` replaces ``settings.seed`` (it shuffles the mini-batches), exactly
as :func:`sdm.experiments.noise_run` does with the run's seed: a fit here on the same noisy targets
gives the same ``theta`` as the Table 2 run. :func:`fit_runs` trains many runs as one program with
:func:`sdm.train.train_runs` (the batching of Table 2's :func:`sdm.experiments.noise_runs`), run for
run bit-identical to :func:`fit`.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Sequence

from ..batch import ConfigurationSet
from ..camera import Camera
from ..experiments import NOISE_GROUP_SIZE
from ..train import TrainSettings, train, train_runs
from .common import FitResult, check_runs, timed, timed_runs

#: SDM's settings are :class:`sdm.TrainSettings` (the noise stage builds them with
#: :func:`sdm.experiments.settings_for` from the tuned cell).
SDMSettings = TrainSettings


def fit(train_set: ConfigurationSet, settings: TrainSettings = TrainSettings(), seed: int = 0,
        camera: Camera | None = None, theta0=(0.0, 0.0)) -> FitResult:
    """Train ``theta`` through the SDM layer (levels ``s..zoom``).

    Returns:
        :class:`~sdm.baselines.common.FitResult`; history stages are the zoom levels.
    """

    def run() -> FitResult:
        history = train(train_set, replace(settings, seed=int(seed)), camera=camera, progress=False,
                        theta0=tuple(float(v) for v in theta0))
        steps = history.to_frame()
        return FitResult(
            history.final_theta, 0.0, len(steps),
            {"stage": steps["level"].tolist(), "loss": steps["loss"].tolist(),
             "a": steps["a"].tolist(), "b": steps["b"].tolist()},
        )

    return timed(run)


def fit_runs(train_sets: Sequence[ConfigurationSet], settings: TrainSettings = TrainSettings(),
             seeds: Sequence[int] = (0,), camera: Camera | None = None, theta0=(0.0, 0.0)) -> list[FitResult]:
    """``R`` independent SDM fits packed as Table 2's noise runs are (:func:`sdm.train.train_runs`, in
    groups of :data:`sdm.experiments.NOISE_GROUP_SIZE`): run ``r`` is ``fit(train_sets[r], settings,
    seeds[r])``, theta for theta, to the bit.

    A start other than ``(0, 0)`` or ``settings.fit_depth`` (which ``train_runs`` does not do) falls
    back to one :func:`fit` per run.

    Args:
        train_sets: ``R`` sets with the same points, offsets and camera, differing only in targets.
        settings: shared; ``seeds[r]`` replaces ``settings.seed`` for run ``r``.
        seeds: ``R`` seeds (mini-batch shuffling).
        camera: default the sets' camera.
        theta0: every run's start ``(a, b)``, metres.

    Returns:
        One :class:`~sdm.baselines.common.FitResult` per run; ``seconds`` is the batched fit's wall
        time divided by ``R``; ``history["loss"]`` is NaN (``train_runs`` records only the loss
        summed over the runs).
    """
    check_runs(train_sets, seeds)
    if tuple(float(v) for v in theta0) != (0.0, 0.0) or settings.fit_depth:
        return [fit(train_set, settings, seed, camera, theta0) for train_set, seed in zip(train_sets, seeds)]

    def run() -> list[FitResult]:
        results = []
        for first in range(0, len(seeds), NOISE_GROUP_SIZE):  # Table 2's groups: larger ones leave the cache
            group = range(first, min(first + NOISE_GROUP_SIZE, len(seeds)))
            history = train_runs(train_sets[0], [train_sets[i].targets for i in group],
                                 [replace(settings, seed=int(seeds[i])) for i in group], camera=camera)
            levels = history.level.tolist()
            for run_index in range(len(group)):
                a, b = history.theta[1:, run_index].unbind(-1)
                results.append(FitResult(
                    tuple(history.theta[-1, run_index].tolist()), 0.0, len(levels),
                    {"stage": levels, "loss": [float("nan")] * len(levels), "a": a.tolist(), "b": b.tolist()},
                ))
        return results

    return timed_runs(run)

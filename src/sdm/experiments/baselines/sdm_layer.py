"""SDM itself, as in Table 2: SGD through the SDM layer with the tuned settings (:func:`sdm.train`).

Kept behind the same ``fit(train_set, settings, seed)`` interface as the baselines so that Table 3
compares like with like. ``seed`` replaces ``settings.seed`` (it shuffles the mini-batches), exactly
as Table 2's runs (:func:`sdm.experiments.noise_runs`) do with the run's seed: a fit here on the same
noisy targets gives the same ``theta`` as the Table 2 run. :func:`fit_runs` trains many runs as one
program as Table 2 does (:func:`sdm.experiments.train_group`), run for run bit-identical to :func:`fit`.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Sequence

from ...batch import ConfigurationSet
from ...camera import Camera
from ..runs import train_group
from ...train import TrainSettings, train
from .common import FitResult, check_runs, timed, timed_runs

#: SDM's settings are :class:`sdm.TrainSettings` (the noise stage builds them with
#: :func:`sdm.experiments.settings_for` from the tuned cell).
SDMSettings = TrainSettings


def fit(train_set: ConfigurationSet, settings: TrainSettings = TrainSettings(), seed: int = 0,
        camera: Camera | None = None, theta0=(0.0, 0.0)) -> FitResult:
    """Train ``theta`` through the SDM layer (levels ``s..zoom``).

    Returns:
        :class:`~sdm.experiments.baselines.common.FitResult`; history stages are the zoom levels.
    """

    def run() -> FitResult:
        history = train(train_set, replace(settings, seed=int(seed)), camera=camera, progress=False,
                        theta0=tuple(float(v) for v in theta0))
        steps = history.to_frame()
        return FitResult(
            history.final_theta, 0.0, len(steps),
            {"stage": steps["zoom"].tolist(), "loss": steps["loss"].tolist(),
             "a": steps["a"].tolist(), "b": steps["b"].tolist()},
        )

    return timed(run)


def fit_runs(train_sets: Sequence[ConfigurationSet], settings: TrainSettings = TrainSettings(),
             seeds: Sequence[int] = (0,), camera: Camera | None = None, theta0=(0.0, 0.0)) -> list[FitResult]:
    """``R`` independent SDM fits as one program, as Table 2 trains its runs
    (:func:`sdm.experiments.train_group`, one :func:`sdm.train.train_runs` call): run ``r`` is
    ``fit(train_sets[r], settings, seeds[r])``, theta for theta, to the bit (with ``fit_depth``, to
    1e-12 m: the depth flow is a float sum). How many runs go together is the caller's choice
    (:func:`sdm.experiments.baselines.baseline_noise_runs` groups them).

    Args:
        train_sets: ``R`` sets with the same points, offsets and camera, differing only in targets.
        settings: shared; ``seeds[r]`` replaces ``settings.seed`` for run ``r``.
        seeds: ``R`` seeds (mini-batch shuffling).
        camera: default the sets' camera.
        theta0: every run's start ``(a, b)``, metres.

    Returns:
        One :class:`~sdm.experiments.baselines.common.FitResult` per run; ``seconds`` is the batched fit's wall
        time divided by ``R``; ``history["loss"]`` is the run's own loss per step.
    """
    check_runs(train_sets, seeds)
    start = [tuple(float(v) for v in theta0)] * len(train_sets)

    def run() -> list[FitResult]:
        history = train_group(train_sets[0], [train_set.targets for train_set in train_sets], settings, seeds, camera,
                              theta0=start)
        zooms = history.zoom.tolist()
        results = []
        for run_index in range(len(train_sets)):
            a, b = history.theta[1:, run_index, :2].unbind(-1)
            results.append(FitResult(
                tuple(history.theta[-1, run_index].tolist()), 0.0, len(zooms),
                {"stage": zooms, "loss": history.loss[:, run_index].tolist(), "a": a.tolist(), "b": b.tolist()},
            ))
        return results

    return timed_runs(run)

"""SDM itself, as in Table 2: SGD through the SDM layer with the tuned settings (:func:`sdm.train`).

Kept behind the same ``fit(train_set, settings, seed)`` interface as the baselines so that Table 3
compares like with like. ``seed`` replaces ``settings.seed`` (it shuffles the mini-batches), exactly
as :func:`sdm.experiments.noise_run` does with the run's seed: a fit here on the same noisy targets
gives the same ``theta`` as the Table 2 run.
"""
from __future__ import annotations

from dataclasses import replace

from ..batch import ConfigurationSet
from ..camera import Camera
from ..train import TrainSettings, train
from .common import FitResult, timed

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

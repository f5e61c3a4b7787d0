"""Gradient-free search on the exact pixel loss: CMA-ES (pycma) on the count of mismatched pixels.

The objective is what a researcher would write without any differentiable renderer: render the
shifted points at zoom 0 exactly as the target was made (``floor(P(Q + (a, b, 0)))``, occupancy,
off-screen points dropped; :func:`sdm.sky.shifted_target`) and count, summed over the training
configurations, the pixels where the rendering and the target disagree (false positives + false
negatives). It is a step function of ``theta``: no gradient, hence CMA-ES, whose ranking-based
update only needs to compare candidates.

The objective is counted fast and exactly by :class:`sdm.experiments.baselines.mismatch.PixelMismatch`
(its module says how).

Budget: at most ``budget`` objective evaluations (pycma's ``maxfevals``; a generation is never cut,
so up to ``popsize - 1`` more), starting from ``theta0`` with step size ``sigma0`` metres. pycma also
stops on its own criteria (``tolx``, flat fitness); the result is the best candidate evaluated.

``cma`` is imported when a fit starts (:func:`sdm.experiments.baselines.pycma.import_cma`): it is a dependency of the
workflow's baseline stage, not of the ``sdm`` library. pycma seeds numpy's global generator with the run's
seed (its ``seed`` option).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Sequence

from ...batch import ConfigurationSet
from ...camera import Camera
from ...errors import SDMInputError
from .common import FitResult, check_positive, check_positive_int, timed
from .mismatch import PixelMismatch, ShiftLayout
from .pycma import import_cma


@dataclass(frozen=True)
class CMAESSettings:
    """Hyper-parameters of the CMA-ES search.

    Attributes:
        sigma0: initial step size, metres (theta* is about 0.6 m from the start (0, 0)).
        budget: objective evaluations allowed.
        popsize: candidates per generation; 0 = pycma's default ``4 + floor(3 ln 2) = 6``.
        tolx: stop when the search distribution is narrower than this, metres.
    """

    sigma0: float = 0.3
    budget: int = 240
    popsize: int = 0
    tolx: float = 1e-5

    def __post_init__(self) -> None:
        check_positive(self, ("sigma0", "tolx"))
        check_positive_int(self, ("budget",))
        check_positive_int(self, ("popsize",), allow_zero=("popsize",))


def cmaes_search(objective: PixelMismatch, settings: CMAESSettings, seed: int, theta0) -> FitResult:
    """One CMA-ES run on ``objective`` (``seconds`` left 0).

    ``objective`` counts candidates of ``theta0``'s length ``d`` (``__call__``, ``many``, ``evaluations``):
    ``d = 2`` for one shared ``(a, b)``, ``2 U`` for a configuration's ``U`` row shifts
    (:mod:`sdm.experiments.baselines.rows`). The result's theta is the best candidate as a ``d``-tuple; the history
    records ``a, b`` of the best so far only when ``d = 2``.
    """
    cma = import_cma()
    options = {
        "seed": int(seed) % (2**31 - 2) + 1,
        "maxfevals": int(settings.budget),
        "tolx": float(settings.tolx),
        "tolfun": 0.0,
        "tolfunhist": 0.0,
        "verbose": -9,
        "verb_disp": 0,
        "verb_log": 0,
    }
    if settings.popsize:
        options["popsize"] = int(settings.popsize)
    strategy = cma.CMAEvolutionStrategy([float(v) for v in theta0], float(settings.sigma0), options)
    planar = len(theta0) == 2
    history = {"stage": [], "loss": [], "a": [], "b": []} if planar else {"stage": [], "loss": []}
    best_value, best_theta = objective(theta0), tuple(float(v) for v in theta0)
    generation = 0
    while not strategy.stop():
        candidates = strategy.ask()
        values = objective.many(candidates)  # the generation in one call (one pass of the compiled count)
        strategy.tell(candidates, values)
        winner = min(range(len(values)), key=values.__getitem__)
        if values[winner] < best_value:
            best_value, best_theta = values[winner], tuple(float(v) for v in candidates[winner])
        history["stage"].append(generation)
        history["loss"].append(float(min(values)))
        if planar:
            history["a"].append(best_theta[0])
            history["b"].append(best_theta[1])
        generation += 1
    return FitResult(best_theta, 0.0, objective.evaluations, history)


def fit(train_set: ConfigurationSet, settings: CMAESSettings = CMAESSettings(), seed: int = 0,
        camera: Camera | None = None, theta0=(0.0, 0.0)) -> FitResult:
    """Minimise :class:`PixelMismatch` with CMA-ES.

    Args:
        seed: seeds pycma (``seed + 1``: pycma treats 0 as "seed from the clock").

    Returns:
        :class:`~sdm.experiments.baselines.common.FitResult`; history has one row per generation (``stage`` =
        generation, ``loss`` = its best count, ``a, b`` = the best candidate so far); ``seconds``
        includes building the objective.

    >>> from sdm import ConfigurationSet, build_configuration, distance
    >>> from sdm.experiments.data.synthetic import synthetic_images
    >>> images = synthetic_images(32)  # the default synthetic data's first 32 images: car centres, metres
    >>> data = ConfigurationSet.from_configurations([build_configuration(image.centres) for image in images])
    >>> result = fit(data, CMAESSettings(budget=120), seed=0)
    >>> result.evaluations, round(distance(result.theta), 3)  # objective calls; metres from SKY_SHIFT
    (127, 0.006)
    """
    return timed(lambda: cmaes_search(PixelMismatch(train_set, camera), settings, seed, theta0))


def fit_runs(train_sets: Sequence[ConfigurationSet], settings: CMAESSettings, seeds: Sequence[int],
             camera: Camera | None = None, theta0=(0.0, 0.0)) -> list[FitResult]:
    """``fit(train_sets[r], settings, seed=seeds[r])`` for every run ``r``, sharing the objective's set-up.

    The runs (e.g. one per noise draw) share points, offsets and camera and differ in their
    targets; the point grouping of :class:`ShiftLayout` is built once (a set with other points gets
    its own) and one table is rewritten from run to run (``N x Hp x Wp`` int16, 47 MB on the
    default data, alive one at a time). The runs are searched one after another, not interleaved:
    pycma draws from numpy's global generator, which its ``seed`` option reseeds at the start of
    each run, so every run draws exactly what it draws in :func:`fit` (and leaves numpy's global
    generator as :func:`fit` of the last run does); its theta, history and evaluation count are
    those of :func:`fit`. A generation's candidates are counted in one call
    (:meth:`PixelMismatch.many`); interleaving the generations of all runs would gain little more:
    every run has its own table (its targets), so the runs share no cached pixels, and it would hold
    every run's table at once.

    Args:
        train_sets: R sets (typically ``train_set.with_targets(noisy)``).
        seeds: R seeds, one per run.

    Returns:
        R :class:`~sdm.experiments.baselines.common.FitResult`; each ``seconds`` is the wall time of all R runs
        (shared set-up included) divided by R.
    """
    train_sets, seeds = list(train_sets), [int(seed) for seed in seeds]
    if len(train_sets) != len(seeds):
        raise SDMInputError(f"fit_runs: {len(train_sets)} train_sets but {len(seeds)} seeds")
    start = time.perf_counter()
    layouts: list[tuple[ConfigurationSet, ShiftLayout]] = []
    results, objective = [], None
    for train_set, seed in zip(train_sets, seeds):
        layout = next((shared for owner, shared in layouts if _same_points(owner, train_set)), None)
        if layout is None:
            layout = ShiftLayout(train_set, camera)
            layouts.append((train_set, layout))
        objective = PixelMismatch(train_set, camera, layout, recycle=objective)
        results.append(cmaes_search(objective, settings, seed, theta0))
    per_run = (time.perf_counter() - start) / max(len(results), 1)
    for result in results:
        result.seconds = per_run
    return results


def _same_points(first: ConfigurationSet, second: ConfigurationSet) -> bool:
    """Whether two sets have the same points per configuration (the targets may differ)."""
    if first.camera != second.camera:
        return False
    if first.points is second.points and first.offsets is second.offsets:
        return True
    return (first.points.shape == second.points.shape and first.offsets.shape == second.offsets.shape
            and torch.equal(first.offsets, second.offsets)
            and torch.equal(first.points, second.points))

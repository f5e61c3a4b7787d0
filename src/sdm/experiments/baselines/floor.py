"""The floor: the theta that minimises the exact pixel mismatch of a run's (noisy) training set.

CMA-ES (:mod:`sdm.experiments.baselines.cmaes`) minimises :class:`~sdm.experiments.baselines.mismatch.PixelMismatch`, the count
of mismatched zoom-0 pixels summed over the training configurations, on a budget (240 counts in
Table 3). Where its minimiser lies is a property of the data, not of any method: the best that any
method minimising that count can reach. :func:`floor_search` finds it with a search thorough enough
that a larger budget no longer moves it, and measures the region around it where the count is minimal;
:func:`floor_runs` does so for the paired runs of every table (:func:`sdm.experiments.paired_runs`).

The search (:class:`FloorSettings`), all on one objective (memoised: a theta counted twice is counted once):

1. ``restarts`` CMA-ES runs (:func:`sdm.experiments.baselines.cmaes.cmaes_search`, ``budget`` counts each): the first
   from ``theta0`` with step size ``sigma0``, restart ``k`` from the best theta so far with
   ``sigma0 * sigma_decay**k`` (the later restarts search ever closer around the incumbent). Then
   theta* itself, where its count is lower than the incumbent's (the floor measures the data, and the
   experiment knows theta*: under noise theta* is often in the minimal region, and a search that stopped in
   a local minimum a few tenths of a millimetre away set a level's mean before, 33% at level 1 on 20 runs).
2. A compass search on the lattice around the best: the 8 neighbours ``best + h (i, j)``,
   ``i, j in {-1, 0, 1}``, in one call; the best of them (the first on ties) replaces the incumbent if
   strictly lower, else ``h`` halves, from ``refine_step`` down to ``refine_tol`` metres.
3. The region: the count is a step function of theta (constant on the cells of a product grid: a
   point's column depends on ``a`` alone, its row on ``b`` alone), minimal on a region that can be
   millimetres wide on sparse data, where every theta is as good as any other. Along ``a`` through the
   search point (``b`` fixed), then along ``b`` through the midpoint of that interval (``a`` fixed), the
   minimal interval's ends are found by probing outwards (``extent_tol * 2**k`` metres, up to
   ``extent_reach``) until the count exceeds the minimum, then bisecting to ``extent_tol``. The
   region's *centre* is ``(midpoint along a, midpoint along b)``, each midpoint checked to count the
   minimum (else the coordinate of the point its line went through: an interval whose ends were found
   past a higher count in between is not one piece), so the centre is in the region; it is the floor's
   theta (a method stopping anywhere in the region is at the floor, and the centre does not depend on
   where in the region a search happened to stop). The intervals' ends are the last minimal probes:
   each is within ``extent_tol`` of a theta where the count is higher. A probe
   that finds a count below the minimum (the compass search stopped in a local minimum) becomes the
   search point, and steps 2-3 run again from it.

Stability is built in: the result also holds the floor of the search's state after its first
``restarts / 2`` restarts (steps 2-3 from that state's best), i.e. of half the budget, so a caller can
tell how far doubling the budget moves the floor without a second search.

Cost and stability on the default data (512 configurations, one thread; benchmarks/studies/floor_budget.py, runs
0..4 per level, on a loaded machine): a count is 0.5-0.9 ms; pycma stops on its own (flat fitness) after
250-450 counts per run, well before a 2,400 budget; with the default 4 restarts a floor costs 1,300-1,550
counts, 0.9-1.1 CPU s per run. Doubling the budget (the half floor against the full one) moves no mean
at levels 0-3 and 5.4% at level 4; from 4 to 8 restarts (runs 0..9) it moves level 4 by 0.3% and level 3 by
-13%: two of ten runs find a minimum 1 pixel lower about 1 mm away. Under strong noise the count has
near-equal minima millimetres apart, so the floor's position there is fixed to about a millimetre, not
to its extent (0.04-0.07e-3 m).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import pandas as pd
import torch

from ...batch import ConfigurationSet
from ...camera import Camera
from ...errors import SDMInputError
from ..runs import paired_runs
from ...metrics import distance
from ...sky import SKY_SHIFT
from .cmaes import CMAESSettings, cmaes_search
from .mismatch import PixelMismatch, ShiftLayout
from .common import check_positive, check_positive_int, field_error


@dataclass(frozen=True)
class FloorSettings:
    """Budget and resolution of :func:`floor_search`.

    Attributes:
        restarts: CMA-ES runs, an even number (the half-budget floor is the state after half of them).
        budget: objective counts allowed per CMA-ES run (pycma's ``maxfevals``; 10x Table 3's 240).
        sigma0: the first run's step size, metres (theta* is about 0.6 m from the start (0, 0)).
        sigma_decay: run ``k`` starts with step size ``sigma0 * sigma_decay**k``, in (0, 1].
        popsize: candidates per generation; 0 = pycma's default (6).
        tolx: a run stops when its distribution is narrower than this, metres.
        refine_step: the compass search's first step, metres.
        refine_tol: its last step (it stops when the step falls below this), metres.
        extent_tol: resolution of the region's ends, metres (the first outward probe and the bisection's end).
        extent_reach: farthest outward probe from the search point, metres; an end not found within it
            is reported at the last minimal probe.
    """

    restarts: int = 4
    budget: int = 2400
    sigma0: float = 0.3
    sigma_decay: float = 0.5
    popsize: int = 0
    tolx: float = 1e-8
    refine_step: float = 1e-2
    refine_tol: float = 1e-6
    extent_tol: float = 1e-6
    extent_reach: float = 1.0

    def __post_init__(self) -> None:
        check_positive_int(self, ("restarts", "budget"))
        check_positive_int(self, ("popsize",), allow_zero=("popsize",))
        check_positive(self, ("sigma0", "sigma_decay", "tolx", "refine_step", "refine_tol", "extent_tol",
                              "extent_reach"))
        if self.restarts % 2:
            raise field_error(self, "restarts", f"must be even (half of them give the half-budget floor), "
                                                f"got {self.restarts!r}")
        if self.sigma_decay > 1:
            raise field_error(self, "sigma_decay", f"must be at most 1, got {self.sigma_decay!r}")
        if self.refine_tol > self.refine_step:
            raise field_error(self, "refine_tol", f"must be at most refine_step ({self.refine_step!r}), "
                                                  f"got {self.refine_tol!r}")
        if self.extent_tol >= self.extent_reach:
            raise field_error(self, "extent_tol", f"must be below extent_reach ({self.extent_reach!r}), "
                                                  f"got {self.extent_tol!r}")

    def cmaes(self, restart: int) -> CMAESSettings:
        """The settings of CMA-ES run ``restart`` (0-based)."""
        return CMAESSettings(sigma0=self.sigma0 * self.sigma_decay**restart, budget=self.budget,
                             popsize=self.popsize, tolx=self.tolx)


@dataclass(frozen=True)
class FloorRegion:
    """Where one search ends and the minimal region around it.

    Attributes:
    The search runs in any number ``d`` of coordinates: ``(a, b)`` for one shared shift, ``2 U`` for a
    configuration's ``U`` row shifts (:mod:`sdm.experiments.baselines.rows`).

    Attributes:
        search_theta: the search's best point (``(a, b)``), metres (after the compass search).
        mismatch: the count there, the minimum found (pixels).
        intervals: per coordinate ``i``, the ``(low, high)`` minimal interval along it through the point whose
            coordinates before ``i`` are already the centre's and the others the search point's, metres
            (``a`` at ``b = search_theta[1]``, then ``b`` at ``a = theta[0]``).
        theta: the region's centre, metres: the midpoints of the intervals (each where the count there is
            ``mismatch``; else the coordinate of the point the interval was measured through); the count
            at ``theta`` is ``mismatch``.
    """

    search_theta: tuple[float, ...]
    mismatch: int
    intervals: tuple[tuple[float, float], ...]
    theta: tuple[float, ...]

    @property
    def interval_a(self) -> tuple[float, float]:
        """The minimal interval along the first coordinate (``a``)."""
        return self.intervals[0]

    @property
    def interval_b(self) -> tuple[float, float]:
        """The minimal interval along the second coordinate (``b``)."""
        return self.intervals[1]

    @property
    def extent(self) -> tuple[float, ...]:
        """The region's width along each coordinate (``a``, ``b``), metres (each within ``2 extent_tol``)."""
        return tuple(high - low for low, high in self.intervals)


@dataclass
class FloorResult:
    """What :func:`floor_search` returns.

    Attributes:
        region: the floor of the whole search.
        half: the floor of its first ``restarts / 2`` CMA-ES runs (half the budget).
        truth: theta* ``(a, b)`` the distances are measured to, metres.
        mismatch_at_truth: the count at theta* (equal to ``min_mismatch`` when theta* is itself a minimiser).
        evaluations: thetas counted (each distinct theta once; the half's extra region search included).
        seconds: wall time of the search.
        restart_best: the count and theta of the best so far after each CMA-ES run.
    """

    region: FloorRegion
    half: FloorRegion
    truth: tuple[float, float]
    mismatch_at_truth: int
    evaluations: int
    seconds: float
    restart_best: list = field(default_factory=list)

    @property
    def theta(self) -> tuple[float, float]:
        """The floor: the minimal region's centre, metres."""
        return self.region.theta

    @property
    def search_theta(self) -> tuple[float, float]:
        return self.region.search_theta

    @property
    def min_mismatch(self) -> int:
        return self.region.mismatch

    @property
    def extent(self) -> tuple[float, float]:
        return self.region.extent

    @property
    def distance(self) -> float:
        """The centre's distance to theta*, metres."""
        return _distance(self.region.theta, self.truth)

    @property
    def search_distance(self) -> float:
        return _distance(self.region.search_theta, self.truth)

    @property
    def half_distance(self) -> float:
        """The half-budget floor's (its region centre's) distance to theta*, metres."""
        return _distance(self.half.theta, self.truth)


def _distance(theta: Sequence[float], truth: Sequence[float]) -> float:
    """Euclidean distance, metres: :func:`sdm.metrics.distance` for ``(a, b)``, over every coordinate beyond."""
    return float(distance(theta, truth)) if len(theta) == 2 else math.dist(theta, truth)


class _Memo:
    """The objective with each distinct theta counted once (the compass search and the region probe the
    same lattice points again); what :func:`~sdm.experiments.baselines.cmaes.cmaes_search` calls (``__call__``, ``many``,
    ``evaluations``)."""

    def __init__(self, objective: PixelMismatch) -> None:
        self.objective, self.counts = objective, {}

    @property
    def evaluations(self) -> int:
        return self.objective.evaluations

    def __call__(self, theta) -> int:
        return self.many([theta])[0]

    def many(self, thetas) -> list[int]:
        keys = [tuple(float(v) for v in theta) for theta in thetas]
        new = list(dict.fromkeys(key for key in keys if key not in self.counts))
        if new:
            self.counts.update(zip(new, self.objective.many(new)))
        return [self.counts[key] for key in keys]


#: The compass search's neighbours in the plane, in the order ties are broken (axes first, then diagonals).
_COMPASS = ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1))


def _neighbours(dimension: int) -> tuple[tuple[int, ...], ...]:
    """The compass directions in ``dimension`` coordinates: :data:`_COMPASS` in the plane; beyond it the
    axes alone (``+e_0, -e_0, +e_1, ...``: ``2 d`` neighbours instead of ``3^d - 1``)."""
    if dimension == 2:
        return _COMPASS
    return tuple(tuple(sign if axis == i else 0 for i in range(dimension))
                 for axis in range(dimension) for sign in (1, -1))


def _compass(count: _Memo, theta: tuple[float, ...], value: int, settings: FloorSettings):
    """The compass search from ``theta`` (count ``value``): ``(theta, value)`` where it stops."""
    step = float(settings.refine_step)
    directions = _neighbours(len(theta))
    while step >= settings.refine_tol:
        candidates = [tuple(v + step * i for v, i in zip(theta, direction)) for direction in directions]
        values = count.many(candidates)
        best = min(range(len(values)), key=values.__getitem__)  # first on ties
        if values[best] < value:
            theta, value = candidates[best], values[best]
        else:
            step *= 0.5
    return theta, value


def _interval(count: _Memo, theta: tuple[float, ...], value: int, axis: int, settings: FloorSettings):
    """The minimal interval along ``axis`` through ``theta`` (count ``value``, taken as the minimum).

    Returns ``((low, high), lower)``: the interval's ends (coordinates along ``axis``, metres; the last
    probes whose count is ``value``) and ``(theta, count)`` of a probe that counted below ``value``,
    else None (then the interval is meaningless: the caller searches again from there).
    """
    tol, reach = float(settings.extent_tol), float(settings.extent_reach)

    def at(offset: float) -> tuple[float, ...]:
        moved = list(theta)
        moved[axis] = theta[axis] + offset
        return tuple(moved)

    # Both directions advance together: one call counts a probe of each (the counts are per candidate,
    # so nothing is spent, and the calls halve).
    inside = [0.0, 0.0]     # farthest minimal offset found, per direction (+, -)
    outside = [None, None]  # nearest offset counted above the minimum beyond it
    reach_step = [tol, tol]
    while True:
        open_ = [d for d in (0, 1) if outside[d] is None and reach_step[d] <= reach]
        if not open_:
            break
        probes = [at(reach_step[d] if d == 0 else -reach_step[d]) for d in open_]
        for d, probe, probe_value in zip(open_, probes, count.many(probes)):
            if probe_value < value:
                return None, (probe, probe_value)
            if probe_value == value:
                inside[d] = reach_step[d]
                reach_step[d] *= 2.0
            else:
                outside[d] = reach_step[d]
    while True:
        open_ = [d for d in (0, 1) if outside[d] is not None and outside[d] - inside[d] > tol]
        if not open_:
            break
        middles = [0.5 * (inside[d] + outside[d]) for d in open_]
        probes = [at(middle if d == 0 else -middle) for d, middle in zip(open_, middles)]
        for d, middle, probe, probe_value in zip(open_, middles, probes, count.many(probes)):
            if probe_value < value:
                return None, (probe, probe_value)
            if probe_value == value:
                inside[d] = middle
            else:
                outside[d] = middle
    return (theta[axis] - inside[1], theta[axis] + inside[0]), None


def _region(count: _Memo, theta: tuple[float, ...], value: int, settings: FloorSettings) -> FloorRegion:
    """Compass search from ``theta``, then the minimal region around where it stops (module docstring, 2-3):
    coordinate after coordinate, each interval through the point whose earlier coordinates are centred."""
    while True:
        theta, value = _compass(count, theta, value, settings)
        line, intervals, lower = tuple(theta), [], None
        for axis in range(len(theta)):
            interval, lower = _interval(count, line, value, axis, settings)
            if lower is None:
                centre, lower = _centre(count, line, value, axis, interval)
            if lower is not None:
                break
            intervals.append(interval)
            line = line[:axis] + (centre,) + line[axis + 1:]
        if lower is None:
            return FloorRegion(theta, int(value), tuple(intervals), line)
        theta, value = lower


def _centre(count: _Memo, theta: tuple[float, ...], value: int, axis: int, interval: tuple[float, float]):
    """``(coordinate, lower)``: the interval's midpoint along ``axis`` if the count there is ``value``; else
    ``theta``'s own coordinate (the interval is not one piece: its ends were found from ``theta`` outwards,
    past a higher count in between); ``lower`` as :func:`_interval`'s."""
    middle = 0.5 * (interval[0] + interval[1])
    point = theta[:axis] + (middle,) + theta[axis + 1:]
    point_value = count(point)
    if point_value < value:
        return None, (point, point_value)
    return (middle if point_value == value else theta[axis]), None


def floor_search(objective: PixelMismatch, seed: int = 0, settings: FloorSettings | None = None,
                 theta0: Sequence[float] = (0.0, 0.0), truth: Sequence[float] = SKY_SHIFT) -> FloorResult:
    """The floor of one objective: its minimiser and minimal region (module docstring).

    Args:
        objective: the exact pixel mismatch of a (noisy) training set.
        seed: seeds the CMA-ES runs (run ``k`` gets a seed drawn from ``(seed, k)``).
        settings: budget and resolution (default :class:`FloorSettings`).
        theta0: the first CMA-ES run's start ``(a, b)`` (or any ``d`` coordinates the objective counts), metres.
        truth: theta* ``(a, b)`` (as many coordinates as ``theta0``), metres, for the distances and
            ``mismatch_at_truth``.

    Returns:
        :class:`FloorResult`. Deterministic: the same objective, seed and settings give the same result.
    """
    settings = FloorSettings() if settings is None else settings
    if not isinstance(settings, FloorSettings):
        raise SDMInputError(f"settings must be FloorSettings, got {type(settings).__name__}")
    truth = tuple(float(v) for v in truth)
    start, first = time.perf_counter(), objective.evaluations
    count = _Memo(objective)
    best_theta = tuple(float(v) for v in theta0)
    if len(best_theta) != len(truth):
        raise SDMInputError(f"theta0 has {len(best_theta)} coordinates, truth {len(truth)}")
    best_value = count(best_theta)
    restart_best, half_state = [], None
    seeds = np.random.SeedSequence([int(seed)]).generate_state(settings.restarts, dtype=np.uint32)
    for restart in range(settings.restarts):
        run = cmaes_search(count, settings.cmaes(restart), int(seeds[restart]), best_theta)
        value = count(run.theta)
        if value < best_value:  # ties keep the incumbent
            best_theta, best_value = tuple(float(v) for v in run.theta), value
        restart_best.append((int(best_value), best_theta))
        if restart + 1 == settings.restarts // 2:
            half_state = (best_theta, best_value)
    # theta* is one more candidate, for both budgets: the floor is a measurement of the data (the experiment
    # knows theta*), not a method, and under noise theta* is often in the minimal region (a search that
    # stops in a local minimum nearby would otherwise set a level's mean)
    at_truth = count(truth)
    if at_truth < best_value:  # ties keep the incumbent
        best_theta, best_value = truth, at_truth
    if at_truth < half_state[1]:
        half_state = (truth, at_truth)
    region = _region(count, best_theta, best_value, settings)
    half = region if half_state == (best_theta, best_value) else _region(count, *half_state, settings)
    return FloorResult(region, half, truth, int(at_truth), objective.evaluations - first,
                       time.perf_counter() - start, restart_best)


#: Columns of :func:`floor_runs`: the run, the floor (the region's centre) ``a, b, distance``, the
#: search's own best point, the region's widths, the counts, the half-budget floor's distance (metres,
#: pixels, seconds).
FLOOR_COLUMNS = ["noise_level", "run", "seed", "a", "b", "distance", "search_a", "search_b", "search_distance",
                 "extent_a", "extent_b", "min_mismatch", "mismatch_at_truth", "half_distance", "evaluations",
                 "seconds"]


def floor_runs(train_set: ConfigurationSet, noise_level: int, runs: Sequence[int], seed: int,
               settings: FloorSettings | None = None, camera: Camera | None = None, *,
               clean_targets: torch.Tensor | None = None, shift: Sequence[float] = SKY_SHIFT,
               group_size: int = 1) -> pd.DataFrame:
    """The floor of each paired run at one noise level, one row each (:data:`FLOOR_COLUMNS`).

    Run ``r`` is every table's run ``(level, r)`` (:func:`sdm.experiments.paired_runs`: the seed
    :func:`sdm.experiments.run_seed` ``(seed, level, r)`` draws its noisy targets and seeds its CMA-ES
    runs). The runs share the point grouping (:class:`~sdm.experiments.baselines.mismatch.ShiftLayout`) and one
    objective table, rewritten from run to run, as :func:`sdm.experiments.baselines.cmaes.fit_runs` does.

    Args:
        train_set: the training configurations (points, camera; its targets are the clean ones unless
            ``clean_targets`` is given).
        seed: the experiment's noise seed (as ``noise.seed`` for Table 2).
        settings: default :class:`FloorSettings`.
        clean_targets: ``(N, H, W)`` bool noise-free targets of ``train_set``'s configurations.
        shift: theta* ``(a, b)``, metres.
        group_size: runs whose noisy targets are drawn at a time (each holds ``N x H x W`` bool).

    Returns:
        :data:`FLOOR_COLUMNS`; ``seconds`` is the run's search and objective set-up, plus its share of
        the point grouping.
    """
    settings = FloorSettings() if settings is None else settings
    if not isinstance(settings, FloorSettings):
        raise SDMInputError(f"settings must be FloorSettings, got {type(settings).__name__}")
    clean = train_set.targets if clean_targets is None else clean_targets
    if clean.shape != train_set.targets.shape or clean.dtype != torch.bool:
        raise SDMInputError(f"clean_targets: expected bool {tuple(train_set.targets.shape)}, "
                            f"got {clean.dtype} {tuple(clean.shape)}")
    start = time.perf_counter()
    layout = ShiftLayout(train_set, camera)
    shared = (time.perf_counter() - start) / max(len(runs), 1)
    state = {"objective": None}

    def fit_group(targets, seeds) -> list[FloorResult]:
        results = []
        for run_targets, run_seed in zip(targets, seeds):
            began = time.perf_counter()
            objective = PixelMismatch(train_set.with_targets(run_targets), camera, layout,
                                      recycle=state["objective"])
            state["objective"] = objective
            result = floor_search(objective, run_seed, settings, truth=shift)
            result.seconds = time.perf_counter() - began + shared
            results.append(result)
        return results

    def record(result: FloorResult) -> dict:
        (a, b), (search_a, search_b), (extent_a, extent_b) = result.theta, result.search_theta, result.extent
        return {"a": a, "b": b, "distance": result.distance, "search_a": search_a, "search_b": search_b,
                "search_distance": result.search_distance, "extent_a": extent_a, "extent_b": extent_b,
                "min_mismatch": result.min_mismatch, "mismatch_at_truth": result.mismatch_at_truth,
                "half_distance": result.half_distance, "evaluations": result.evaluations,
                "seconds": result.seconds}

    return paired_runs(clean, noise_level, runs, seed, fit_group, record, FLOOR_COLUMNS, group_size)


__all__ = ["FLOOR_COLUMNS", "FloorRegion", "FloorResult", "FloorSettings", "floor_runs", "floor_search"]

"""CMA-ES and the floor on per-row shifts, one configuration at a time.

With parameters attached to points (:mod:`sdm.sharing`), a configuration's points move by the total
shifts of its units (its rows, or under ``camera+car`` its cars' camera + residual sums). A black-box
search solves each configuration alone, over all of its unknowns at once: ``2 U`` numbers for ``U``
units.

The objective (:class:`ConfigurationMismatch`) is Table 3's exact pixel loss restricted to one
configuration: render its points moved by their units' shifts exactly as the targets are made
(``floor(P(Q + (shift, 0)))``, :func:`sdm.experiments.baselines.common.project_shifted`, occupancy, off-screen points
dropped) and count the pixels where the rendering and the target disagree. A whole CMA-ES generation is
counted in one pass (``C`` candidates, ``p`` points: ``(C, p)`` tensors): every point writes its number
into its pixel's entry of a per-candidate stamp table, and only the point that reads its own number back
counts its pixel, with weight ``+1`` off the target and ``-1`` on it::

    mismatch = |target| + sum over the distinct rendered pixels of w

No table of ``C x H x W`` cells is cleared per call (every entry read was written in that call). The
set-wide grouped count of :mod:`sdm.experiments.baselines.mismatch` (and its compiled kernel) serves one shared ``theta``
over many configurations; here a configuration has a few hundred points and many candidates, so the
points are counted directly (``tests/baselines/test_rows.py`` holds the count to the straightforward rendering).

Budget (:class:`RowsCMAESSettings`): ``evaluations_per_unknown`` counts per unknown (``2 U``) of the
configuration, so a configuration with more cars gets proportionally more; pycma stops earlier on its
own criteria (flat fitness, ``tolx``).

The floor (:func:`floor_configurations`): :func:`sdm.experiments.baselines.floor.floor_search` on one
configuration's count, started at theta*'s totals with a small step size and a larger budget: the centre
of the minimal region that a search started at theta* reaches (the minimiser nearest theta*).

``cma`` is imported when a search starts (a dependency of the workflow's baseline stage).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
import torch

from ...batch import ConfigurationSet
from ...camera import Camera
from ...errors import SDMInputError
from ...representation import screen_pixels
from ...sharing import Units, check_theta
from .cmaes import CMAESSettings, cmaes_search
from .common import check_positive, check_positive_int, field_error, project_shifted
from .floor import FloorSettings, floor_search


class ConfigurationMismatch:
    """The exact zoom-0 pixel mismatch of one configuration as a function of its units' shifts.

    Args:
        points: ``(p, 3)`` float64 the configuration's points ``Q``, metres.
        unit: ``(p,)`` int64 each point's unit in ``[0, U)``.
        target: ``(H, W)`` bool the configuration's (possibly noisy) target.
        camera: camera and screen.
        window: ``(row, col, height, width)`` screen pixels, or None (the whole screen): count the mismatch within
            this window only, pixels outside it counted as off screen. For a caller that knows no candidate
            changes a pixel outside it (:func:`sdm.experiments.identifiability.exact_sets`); the stamp buffer then needs a cell
            per window pixel, not per screen pixel.

    A candidate is ``2 U`` numbers: unit ``u``'s shift ``(a, b)`` at ``[2u, 2u + 1]``.

    Attributes:
        evaluations: candidates counted so far.
        n_units: ``U``.
    """

    def __init__(self, points: torch.Tensor, unit: torch.Tensor, target: torch.Tensor, camera: Camera,
                 window: tuple[int, int, int, int] | None = None) -> None:
        if points.ndim != 2 or points.shape[1] != 3 or unit.shape != points.shape[:1]:
            raise SDMInputError(f"points must be (p, 3) and unit (p,), got {tuple(points.shape)} and "
                                f"{tuple(unit.shape)}")
        if tuple(target.shape) != camera.screen_shape:
            raise SDMInputError(f"target must be {camera.screen_shape}, got {tuple(target.shape)}")
        self.points, self.unit, self.camera = points, unit.to(torch.int64), camera
        self.n_units = int(unit.max()) + 1 if unit.numel() else 0
        if window is None:
            window = (0, 0) + tuple(camera.screen_shape)
        top, left, height, width = (int(v) for v in window)
        if top < 0 or left < 0 or height < 1 or width < 1 or top + height > camera.screen_shape[0] \
                or left + width > camera.screen_shape[1]:
            raise SDMInputError(f"window must lie on the {camera.screen_shape} screen, got {window!r}")
        self._window = (top, left, height, width)
        target = target[top:top + height, left:left + width]
        self._cells = height * width
        # weight per pixel (+1 off target, -1 on target), then a spare cell of weight 0 for off-screen points
        weight = torch.ones(self._cells + 1, dtype=torch.int64, device=points.device)
        weight[:-1][target.reshape(-1)] = -1
        weight[-1] = 0
        self._weight = weight
        self.n_target = int(target.sum())
        self._stamp = torch.empty(0, dtype=torch.int64, device=points.device)
        self.evaluations = 0

    def __call__(self, candidate) -> int:
        return self.many([candidate])[0]

    @property
    def cells(self) -> int:
        """Stamp cells one candidate takes: the window's pixels and a spare one."""
        return self._cells + 1

    def counts(self, shifts: torch.Tensor) -> torch.Tensor:
        """``(C,)`` int64 mismatches of ``(C, U, 2)`` float64 unit shifts (metres), one pass for all ``C``."""
        n_candidates, n_points = shifts.shape[0], self.points.shape[0]
        per_point = shifts.index_select(1, self.unit)  # (C, p, 2)
        pixels, on = screen_pixels(project_shifted(self.points, per_point, self.camera), self.camera)
        top, left, height, width = self._window
        row, col = pixels[..., 0] - top, pixels[..., 1] - left
        on = on & (row >= 0) & (row < height) & (col >= 0) & (col < width)
        cell = torch.where(on, row * width + col, self._cells)  # (C, p), spare off screen (or off the window)
        stride = self._cells + 1
        ids = (cell + torch.arange(n_candidates, device=cell.device).unsqueeze(1) * stride).reshape(-1)
        if self._stamp.numel() < n_candidates * stride:
            self._stamp = torch.empty(n_candidates * stride, dtype=torch.int64, device=cell.device)
        number = torch.arange(ids.numel(), device=cell.device)
        self._stamp.index_put_((ids,), number)  # a pixel written twice keeps one writer's number
        survivor = self._stamp.index_select(0, ids) == number  # one point per distinct (candidate, pixel)
        weight = torch.where(survivor, self._weight.index_select(0, cell.reshape(-1)), 0)
        return self.n_target + weight.view(n_candidates, n_points).sum(1)

    def many(self, candidates) -> list[int]:
        """The mismatch of each candidate (``2 U`` numbers each: a CMA-ES generation)."""
        self.evaluations += len(candidates)
        shifts = torch.as_tensor(np.asarray(candidates, dtype=np.float64), device=self.points.device)
        if shifts.ndim != 2 or shifts.shape[1] != 2 * self.n_units:
            raise SDMInputError(f"candidates must have {2 * self.n_units} coordinates each, got "
                                f"{tuple(shifts.shape)}")
        return self.counts(shifts.view(shifts.shape[0], self.n_units, 2)).tolist()


def configuration_objective(data: ConfigurationSet, units: Units, index: int) -> ConfigurationMismatch:
    """The :class:`ConfigurationMismatch` of configuration ``index`` of ``data`` (its own target) under ``units``."""
    start, stop = int(data.offsets[index]), int(data.offsets[index + 1])
    first_unit = int(units.offsets[index])
    return ConfigurationMismatch(data.points[start:stop], units.point_unit[start:stop] - first_unit,
                                 data.targets[index], data.camera)


@dataclass(frozen=True)
class RowsCMAESSettings:
    """CMA-ES per configuration over its ``2 U`` unknowns.

    Attributes:
        evaluations_per_unknown: the budget rule: at most this many counts per unknown, ``c x 2U`` per
            configuration (pycma's ``maxfevals``; a generation is never cut).
        sigma0: initial step size, metres (theta* is about 0.6 m from the start (0, 0)).
        popsize: candidates per generation; 0 = pycma's default ``4 + floor(3 ln 2U)``.
        tolx: stop when the search distribution is narrower than this, metres.
        penalty: the regularised search's weight: the count plus ``penalty`` per unit per ``(0.1 m)^2`` of its squared
            distance from its start (:class:`Penalised`); 0 searches the count alone.
    """

    evaluations_per_unknown: int = 150
    sigma0: float = 0.3
    popsize: int = 0
    tolx: float = 1e-5
    penalty: float = 0.0

    def __post_init__(self) -> None:
        check_positive(self, ("sigma0", "tolx"))
        if isinstance(self.penalty, bool) or not isinstance(self.penalty, (int, float)) or not self.penalty >= 0 \
                or self.penalty == float("inf"):
            raise field_error(self, "penalty", f"must be a non-negative number, got {self.penalty!r}")
        check_positive_int(self, ("evaluations_per_unknown",))
        check_positive_int(self, ("popsize",), allow_zero=("popsize",))

    def cmaes(self, n_unknowns: int) -> CMAESSettings:
        """The CMA-ES settings of a configuration with ``n_unknowns`` (``2 U``) unknowns."""
        return CMAESSettings(sigma0=self.sigma0, budget=self.evaluations_per_unknown * n_unknowns,
                             popsize=self.popsize, tolx=self.tolx)


@dataclass
class RowsResult:
    """Per-configuration estimates of every unit's total shift.

    Attributes:
        totals: ``(U, 2)`` float64 the estimated total shift of each unit, metres (row order of ``units``).
        mismatch: ``(N,)`` int64 each configuration's count at its estimate (0 for an empty configuration).
        evaluations: ``(N,)`` int64 counts spent per configuration.
        seconds: ``(N,)`` float64 CPU seconds per configuration (``time.process_time``: objective set-up,
            search and count), 0 for a configuration without units.
    """

    totals: torch.Tensor
    mismatch: torch.Tensor
    evaluations: torch.Tensor
    seconds: torch.Tensor


def configuration_seed(seed: int, index: int) -> int:
    """The seed of configuration ``index``'s search in a run seeded ``seed`` (a hash of the two)."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1, dtype=np.uint32)[0])


def _check_units(data: ConfigurationSet, units: Units) -> None:
    if not isinstance(units, Units) or units.point_unit.shape[0] != data.points.shape[0] \
            or units.offsets.shape[0] != len(data) + 1:
        raise SDMInputError("units must be sdm.sharing.units(data, param_index) of this set")


def _start(theta0, units: Units, name: str) -> torch.Tensor:
    """``(U, 2)`` float64 start totals, a tensor of its own: ``theta0`` ``(U, 2)``, or zeros when None.

    A copy always: the searches write their results into it row by row, and a caller's ``theta0`` may be a view
    whose rows share memory (``shared.expand(U, 2)``), where each row written would overwrite every other.
    """
    if theta0 is None:
        return torch.zeros(len(units), 2, dtype=torch.float64)
    return check_theta(theta0, len(units), name=name).detach().to(device="cpu", dtype=torch.float64, copy=True)


def fit_configurations(data: ConfigurationSet, units: Units, settings: RowsCMAESSettings = RowsCMAESSettings(),
                       seed: int = 0, theta0=None, configs=None) -> RowsResult:
    """CMA-ES on each configuration's exact pixel mismatch over all of its units' shifts.

    Args:
        data: the configurations and their (possibly noisy) targets.
        units: :func:`sdm.sharing.units` of ``data`` under the parameter index.
        settings: the budget rule and step size; ``settings.penalty > 0``: the regularised search, the count plus a
            penalty on the distance from the start (:class:`Penalised`).
        seed: the run's seed; configuration ``i`` is searched with :func:`configuration_seed` ``(seed, i)``.
        theta0: ``(U, 2)`` start totals, metres (default zeros: where SDM starts).
        configs: the configurations to search (default all); the others keep their start, 0 counts.

    Returns:
        :class:`RowsResult`. Deterministic: the same arguments give the same totals.
    """
    if not isinstance(settings, RowsCMAESSettings):
        raise SDMInputError(f"settings must be RowsCMAESSettings, got {type(settings).__name__}")
    _check_units(data, units)
    totals = _start(theta0, units, "theta0")
    mismatch, evaluations, seconds = _per_configuration(len(data))
    for index, own, objective, start, began in _each_configuration(data, units, configs, totals):
        searched = Penalised(objective, start, settings.penalty) if settings.penalty else objective
        result = cmaes_search(searched, settings.cmaes(len(start)), configuration_seed(seed, index), start)
        mismatch[index] = objective(result.theta)
        seconds[index] = time.process_time() - began
        evaluations[index] = objective.evaluations - 1  # the closing count is not the search's
        totals[own] = torch.tensor(result.theta, dtype=torch.float64).view(-1, 2)
    return RowsResult(totals, mismatch, evaluations, seconds)


class Penalised:
    """A count plus ``weight`` per ``(0.1 m)^2`` of the candidate's squared distance from ``start`` (2 U floats).

    The regularised exact-mismatch search: under noise the count's minimisers fit the noise, and a practitioner
    keeps the search near its start. ``weight`` 0 is the count itself.
    """

    def __init__(self, objective, start, weight: float) -> None:
        self.objective, self.start, self.weight = objective, np.asarray(start, dtype=np.float64), float(weight)

    @property
    def evaluations(self) -> int:
        return self.objective.evaluations

    def _penalty(self, candidates) -> np.ndarray:
        gap = np.asarray(candidates, dtype=np.float64) - self.start
        return self.weight * (gap**2).sum(-1) / 0.01

    def __call__(self, candidate) -> float:
        return self.many([candidate])[0]

    def many(self, candidates) -> list[float]:
        counts = np.asarray(self.objective.many(candidates), dtype=np.float64)
        return (counts + self._penalty(candidates)).tolist() if self.weight else counts.tolist()


class _Block:
    """One unit's 2 unknowns of a configuration's count, the other units held at ``current`` (a list of 2 U floats,
    read at each count: the sweep writes a block's result into it before the next block)."""

    def __init__(self, objective: ConfigurationMismatch, current: list[float], unit: int) -> None:
        self.objective, self.current, self.unit = objective, current, unit

    @property
    def evaluations(self) -> int:
        return self.objective.evaluations

    def _full(self, candidate) -> list[float]:
        full = list(self.current)
        full[2 * self.unit:2 * self.unit + 2] = [float(candidate[0]), float(candidate[1])]
        return full

    def __call__(self, candidate) -> int:
        return self.objective.many([self._full(candidate)])[0]

    def many(self, candidates) -> list[int]:
        return self.objective.many([self._full(candidate) for candidate in candidates])


def fit_blocks(data: ConfigurationSet, units: Units, settings: RowsCMAESSettings = RowsCMAESSettings(),
               seed: int = 0, theta0=None, configs=None, sweeps: int = 2) -> RowsResult:
    """CMA-ES per unit: block sweeps over each configuration's units, each unit's 2 unknowns in turn with the others
    fixed, on the configuration's whole exact pixel mismatch (:class:`ConfigurationMismatch`).

    The budget is :func:`fit_configurations`'s (``evaluations_per_unknown x 2U`` per configuration), split evenly
    over ``sweeps`` sweeps of its ``U`` units: each block search gets ``2 x evaluations_per_unknown / sweeps``
    counts (at least one generation). Block ``(sweep, u)`` of configuration ``i`` is seeded from
    ``(seed, i, sweep, u)``; a block keeps its start unless a candidate counts less (with ``settings.penalty``, the
    count plus the unit's penalty from its start, :class:`Penalised`).

    Returns:
        :class:`RowsResult`. Deterministic: the same arguments give the same totals.
    """
    if not isinstance(settings, RowsCMAESSettings):
        raise SDMInputError(f"settings must be RowsCMAESSettings, got {type(settings).__name__}")
    if isinstance(sweeps, bool) or not isinstance(sweeps, int) or sweeps < 1:
        raise SDMInputError(f"sweeps must be a positive integer, got {sweeps!r}")
    _check_units(data, units)
    totals = _start(theta0, units, "theta0")
    mismatch, evaluations, seconds = _per_configuration(len(data))
    block = replace(settings, evaluations_per_unknown=max(1, (2 * settings.evaluations_per_unknown) // sweeps))
    for index, own, objective, start, began in _each_configuration(data, units, configs, totals):
        current = list(start)
        for sweep in range(sweeps):
            for unit in range(len(current) // 2):
                block_seed = int(np.random.SeedSequence([int(seed), int(index), sweep, unit]).generate_state(
                    1, dtype=np.uint32)[0])
                own_start = start[2 * unit:2 * unit + 2]
                searched = _Block(objective, current, unit)
                searched = Penalised(searched, own_start, settings.penalty) if settings.penalty else searched
                result = cmaes_search(searched, block.cmaes(1), block_seed, current[2 * unit:2 * unit + 2])
                current[2 * unit:2 * unit + 2] = [float(v) for v in result.theta]
        evaluations[index] = objective.evaluations
        mismatch[index] = objective(current)
        seconds[index] = time.process_time() - began
        totals[own] = torch.tensor(current, dtype=torch.float64).view(-1, 2)
    return RowsResult(totals, mismatch, evaluations, seconds)


def _per_configuration(n_configs: int):
    return (torch.zeros(n_configs, dtype=torch.int64), torch.zeros(n_configs, dtype=torch.int64),
            torch.zeros(n_configs, dtype=torch.float64))


def _each_configuration(data: ConfigurationSet, units: Units, configs, start: torch.Tensor):
    """Per configuration of ``configs`` (default all) that has units, in order: ``(index, its units' slice,
    its objective, its start as 2U floats, the process time before the objective was built)``."""
    chosen = range(len(data)) if configs is None else data.check_indices(configs, "configs").tolist()
    for index in chosen:
        first, last = int(units.offsets[index]), int(units.offsets[index + 1])
        if first == last:
            continue
        began = time.process_time()
        objective = configuration_objective(data, units, index)
        yield index, slice(first, last), objective, start[first:last].reshape(-1).tolist(), began


@dataclass(frozen=True)
class RowsFloorSettings:
    """The floor per configuration: :class:`~sdm.experiments.baselines.floor.FloorSettings` with a budget per unknown.

    Attributes:
        evaluations_per_unknown: each CMA-ES restart's budget per unknown (``c x 2U``), 4x the search's.
        restarts: CMA-ES runs from theta*'s totals (even: the half-budget floor is after half of them).
        sigma0: the first restart's step size, metres: small, the search starts at theta*.
        floor: the rest of the floor's settings (compass search and region resolution); its ``restarts``,
            ``budget`` and ``sigma0`` are replaced by the above.
    """

    evaluations_per_unknown: int = 600
    restarts: int = 2
    sigma0: float = 0.02
    floor: FloorSettings = FloorSettings()

    def __post_init__(self) -> None:
        check_positive_int(self, ("evaluations_per_unknown", "restarts"))
        check_positive(self, ("sigma0",))
        if not isinstance(self.floor, FloorSettings):
            raise SDMInputError(f"RowsFloorSettings.floor must be FloorSettings, got {type(self.floor).__name__}")
        self.settings(2)  # the combination is checked once here

    def settings(self, n_unknowns: int) -> FloorSettings:
        """The floor settings of a configuration with ``n_unknowns`` (``2 U``) unknowns."""
        return replace(self.floor, restarts=self.restarts, budget=self.evaluations_per_unknown * n_unknowns,
                       sigma0=self.sigma0)


@dataclass
class RowsFloor:
    """The floor of each configuration, per unit.

    Attributes:
        totals: ``(U, 2)`` float64 the floor's total shift of each unit, metres: the exact-mismatch minimiser
            nearest theta* of those the search knows (:func:`nearest_minimiser`): theta* itself wherever it
            attains the least count (always without noise), else the nearer to it of the search's point and the
            minimal region's centre among those at the least count.
        centre_totals: ``(U, 2)`` the minimal region's centre.
        search_totals: ``(U, 2)`` where the search itself stopped.
        min_mismatch: ``(N,)`` int64 the count at the floor; mismatch_at_truth: ``(N,)`` the count at theta*.
        evaluations, seconds: ``(N,)`` counts and CPU seconds per configuration.
    """

    totals: torch.Tensor
    centre_totals: torch.Tensor
    search_totals: torch.Tensor
    min_mismatch: torch.Tensor
    mismatch_at_truth: torch.Tensor
    evaluations: torch.Tensor
    seconds: torch.Tensor


def floor_configurations(data: ConfigurationSet, units: Units, truth: torch.Tensor,
                         settings: RowsFloorSettings = RowsFloorSettings(), seed: int = 0, configs=None) -> RowsFloor:
    """The floor of each configuration: :func:`~sdm.experiments.baselines.floor.floor_search` started at theta*.

    Args:
        truth: ``(U, 2)`` theta*'s unit totals (:func:`sdm.sharing.unit_totals`), metres.
        seed: configuration ``i``'s restarts are seeded from :func:`configuration_seed` ``(seed, i)``.
        configs: the configurations to search (default all); the others keep theta*, 0 counts.
    """
    if not isinstance(settings, RowsFloorSettings):
        raise SDMInputError(f"settings must be RowsFloorSettings, got {type(settings).__name__}")
    _check_units(data, units)
    truth = _start(truth, units, "truth")
    totals, centre_totals, search_totals = truth.clone(), truth.clone(), truth.clone()
    min_mismatch, evaluations, seconds = _per_configuration(len(data))
    at_truth = torch.zeros(len(data), dtype=torch.int64)
    for index, own, objective, start, began in _each_configuration(data, units, configs, truth):
        result = floor_search(objective, configuration_seed(seed, index), settings.settings(len(start)),
                              theta0=start, truth=start)
        centre_totals[own] = torch.tensor(result.theta, dtype=torch.float64).view(-1, 2)
        search_totals[own] = torch.tensor(result.search_theta, dtype=torch.float64).view(-1, 2)
        nearest, least = nearest_minimiser(objective, start, (result.search_theta, result.theta))
        totals[own] = torch.tensor(nearest, dtype=torch.float64).view(-1, 2)
        min_mismatch[index], at_truth[index] = least, result.mismatch_at_truth
        evaluations[index] = result.evaluations
        seconds[index] = time.process_time() - began
    return RowsFloor(totals, centre_totals, search_totals, min_mismatch, at_truth, evaluations, seconds)


def nearest_minimiser(objective: ConfigurationMismatch, truth, candidates) -> tuple[list[float], int]:
    """Of theta* and ``candidates`` (each ``2 U`` numbers), the one nearest theta* among those at the least count.

    Returns:
        ``(theta, count)``: the chosen point (theta* itself wherever it attains the least count) and that count.
    """
    truth = [float(v) for v in truth]
    points = [truth] + [[float(v) for v in point] for point in candidates]
    counts = objective.many(points)
    least = min(counts)
    at_least = [point for point, count in zip(points, counts) if count == least]
    nearest = min(at_least, key=lambda point: sum((p - t) ** 2 for p, t in zip(point, truth)))
    return nearest, int(least)


__all__ = ["ConfigurationMismatch", "Penalised", "RowsCMAESSettings", "RowsFloor", "RowsFloorSettings", "RowsResult",
           "configuration_objective", "configuration_seed", "fit_blocks", "fit_configurations",
           "floor_configurations",
           "nearest_minimiser"]

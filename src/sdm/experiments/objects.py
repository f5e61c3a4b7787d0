"""Parameters attached to points, measured (Table 6 and the scaling with the number of unknowns).

The paper's title problem: every point carries its own shift, and the camera is the sharing of shifts
between points (:mod:`sdm.sharing`). Table 2 solves its special case, one shift for everything. Here
the shifts are one per configuration, one per car, or a camera per configuration plus a residual per
car, each drawn from :class:`sdm.sharing.TruthDistribution`; the targets are rendered from them
(:func:`sdm.sharing.render_targets`) and get Table 2's noise. Every method sees the same targets of a
run (paired runs, :func:`sdm.experiments.run_seed`) and is scored per *unit* (:class:`sdm.sharing.Units`:
a configuration's row, a car's row, or a car's camera + residual total), the quantity a configuration's
pixels identify.

The methods (:data:`METHODS`):

* ``sdm_paper``: SDM with the paper's rule. First the paper's coarse-to-fine training on one shared shift (the camera
  concept at its coarsest: one row for the run's configurations; :attr:`ObjectsSettings.warm`), then every
  row from that start (:attr:`ObjectsSettings.rows`: levels ``s..0``, each row at the same rate per point,
  :func:`sdm.train.rates_per_point`). A lone car's disc at the coarse levels sits inside its target's
  block and is pulled by nothing: started from (0, 0) the rows barely move (docs/method/objects.md).
* ``sdm_schedule``: the same with the recommended schedule (its rule for both stages, then its
  refinement on the rows).
* ``cmaes``: CMA-ES per configuration over all of its units (:func:`sdm.experiments.baselines.rows.fit_configurations`),
  started from SDM's shared estimate (the same start as SDM's rows).
* ``cmaes_car``: CMA-ES per unit (:func:`sdm.experiments.baselines.rows.fit_blocks`): block sweeps over each configuration's
  units, each unit's 2 unknowns with the others fixed, on the whole image's exact mismatch, with the same total
  evaluations as ``cmaes`` and from the same start.
* ``cmaes_reg``: the regularised search: ``cmaes`` on the count plus ``research.objects.cmaes.penalty`` per unit per
  ``(0.1 m)^2`` of its squared distance from its start (:class:`sdm.experiments.baselines.rows.Penalised`), the answer to
  the count's minimisers fitting the noise. ``cmaes`` and ``cmaes_car`` search the count alone.
* ``silhouette``: the soft-silhouette baseline on the rows, from the same start.
* ``floor``: each configuration's exact-mismatch minimiser nearest theta*
  (:func:`sdm.experiments.baselines.rows.floor_configurations`; theta* itself without noise).

What the pixels identify (:data:`EXACT_SET`, where asked for): on a job's first run, each unit's set of shifts that
reproduce its noise-free target exactly (the others at theta*), its extent per axis and the mean distance of its
points from theta*, the error of a method that lands anywhere in it.

The prior gate (:func:`sdm.experiments.gate.prior_gate`), scored beside every method where a unit is one row (the configuration
and car levels): each unit whose estimate ends farther from the method's start than :attr:`ObjectsSettings.gate`
standard deviations of its prior (:func:`sdm.experiments.gate.prior_sd`) is returned to that start (record column ``gated``).
No method's rule knows the prior; the gate is the check a practitioner who knows it adds to any of them, as the
regularised search adds its penalty.

The do-nothing references (:data:`REFERENCES`), scored on the same units: ``start``, the paper's rule's shared
start that SDM's paper-rule rows, CMA-ES and the silhouette are given, and ``prior``, theta*'s mean (the centre
of :class:`sdm.sharing.TruthDistribution`, a guess that looks at no pixel). Every record carries the distance of
its own method's start on its unit (``start``), so that each method's error reads as a paired fraction of it.

CPU seconds per configuration: the method's process time for the run over the configurations that own
units (SDM's and the per-configuration baselines' shared start included in each method that uses it).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Sequence

import pandas as pd
import torch
from tqdm.std import tqdm  # plain text: renders in notebooks without ipywidgets

from .. import sharing as S
from .baselines import silhouette
from .baselines.rows import (RowsCMAESSettings, RowsFloorSettings, configuration_objective, fit_blocks,
                             fit_configurations, floor_configurations)
from .baselines.silhouette import SilhouetteSettings
from ..batch import ConfigurationSet
from ..errors import SDMInputError
from .runs import noisy_targets, run_seed
from .gate import prior_gate, prior_sd, prior_zooms
from .identifiability import exact_sets
from ..train import TrainSettings, parse_schedule, rates_per_point, refine_runs, train_runs

#: The methods of Table 6, in its row order.
METHODS = ("sdm_paper", "sdm_schedule", "cmaes", "cmaes_car", "cmaes_reg", "silhouette", "floor")
#: The do-nothing references of Table 6, scored beside the methods (no fit; see the module's text).
REFERENCES = ("start", "prior")
#: What the pixels identify: a unit's exact-match set (:func:`sdm.experiments.identifiability.exact_sets`), scored on the units of
#: a job's first run (its mean distance from theta*; the set's extent per axis in ``extent_a``, ``extent_b``).
EXACT_SET = "exact_set"
#: Where SDM's rows start training (:attr:`ObjectsSettings.first_zoom`).
FIRST_ZOOMS = ("s", "prior")


@dataclass(frozen=True)
class ObjectsSettings:
    """Everything a run of Table 6 needs besides its data.

    Attributes:
        warm: the shared start's schedule (the paper's: levels ``s..0``, ``n_epoch`` epochs each).
        rows: the rows' schedule; its ``lr`` is per row at the mean points per row (``rates_per_point``).
        schedule: the recommended schedule's name (``"RULE+REFINE:E"``, :func:`sdm.train.parse_schedule`).
        cmaes, floor, silhouette: the baselines' settings (``sdm.experiments.baselines``).
        truth: how theta* is drawn.
        car_sigma0: CMA-ES per car's initial step, metres (``cmaes.sigma0`` is the joint and regularised searches').
        gate: the prior gate, in standard deviations of a row's prior (:func:`prior_gate`).
        first_zoom: where SDM's rows start training: ``"s"``, every row at ``rows.s`` (the paper's coarse-to-fine training), or
            ``"prior"``, each row at the zoom whose block covers its prior spread (:func:`sdm.experiments.gate.prior_zooms`),
            at ``rows.lr`` there (the chain still runs from ``rows.s``).
    """

    warm: TrainSettings
    rows: TrainSettings
    schedule: str
    cmaes: object
    floor: object
    silhouette: object
    truth: S.TruthDistribution = S.TruthDistribution()
    car_sigma0: float = 0.3
    gate: float = 3.5
    first_zoom: str = "s"

    def __post_init__(self):
        if self.first_zoom not in FIRST_ZOOMS:
            raise SDMInputError(f"first_zoom must be one of {', '.join(FIRST_ZOOMS)}, got {self.first_zoom!r}")


def _cpu() -> float:
    return time.process_time()


def shared_start(data: ConfigurationSet, targets: torch.Tensor, seed: int, settings: ObjectsSettings,
                 rule: str = "paper") -> tuple[torch.Tensor, float]:
    """SDM's shared start: the schedule ``settings.warm`` with rule ``rule`` on one shift for every point.

    Returns:
        ``(shared (2,), seconds)``: the shift (metres) and the CPU seconds it took.
    """
    began = _cpu()
    shared = train_runs(data, [targets], [replace(settings.warm, rule=rule, seed=seed)]).theta[-1, 0]
    return shared, _cpu() - began


def sdm_rows(data: ConfigurationSet, targets: torch.Tensor, sharing: S.Sharing, seed: int, settings: ObjectsSettings,
             schedule: str | None, start: tuple[torch.Tensor, float] | None = None
             ) -> tuple[torch.Tensor, torch.Tensor, float, float]:
    """SDM on the rows of ``sharing``: the shared start, then the rows (``schedule``: ``None`` for the paper's rule).

    ``start``: the shared start of the schedule's rule (:func:`shared_start`) where the caller has it already;
    its seconds count in the fit's as if it were trained here.

    Returns:
        ``(theta (K, 2), shared (2,), seconds, shared_seconds)``: the rows' estimate, the shared start (metres),
        the CPU seconds of the whole fit and of its shared start.
    """
    rule, refine = parse_schedule(schedule) if schedule else ("paper", None)
    shared, shared_seconds = start if start is not None else shared_start(data, targets, seed, settings, rule)
    began = _cpu()
    rows = [replace(settings.rows, rule=rule, seed=seed)]
    row_rate, row_zoom = rates_per_point(sharing.param_index), None
    if settings.first_zoom == "prior":  # each row at rows.lr at its own first zoom, halved per zoom below it
        row_zoom = prior_zooms(data, sharing, prior_sd(sharing, settings.truth), settings.rows.s)
        row_rate = row_rate * 2.0 ** (settings.rows.s - row_zoom).to(torch.float64)
    history = train_runs(data, [targets], rows, theta0=[_start_table(sharing, shared)],
                         param_index=sharing.param_index, row_rate=row_rate, row_zoom=row_zoom)
    if refine is not None:
        history = refine_runs(data, [targets], rows, history, refine, param_index=sharing.param_index,
                              row_rate=row_rate)
    return history.theta[-1, 0], shared, _cpu() - began + shared_seconds, shared_seconds


def search_units(method: str, data: ConfigurationSet, units: S.Units, settings: ObjectsSettings, seed: int,
                 theta0: torch.Tensor):
    """One of the black-box searches on every configuration's exact count, from ``theta0`` ``(U, 2)`` metres:
    ``cmaes`` (joint, the count alone), ``cmaes_car`` (block sweeps, ``settings.car_sigma0``) or ``cmaes_reg``
    (joint, with ``settings.cmaes.penalty``). Returns :class:`sdm.experiments.baselines.rows.RowsResult`."""
    if method == "cmaes_car":
        return fit_blocks(data, units, replace(settings.cmaes, penalty=0.0, sigma0=settings.car_sigma0), seed,
                          theta0=theta0)
    penalty = settings.cmaes.penalty if method == "cmaes_reg" else 0.0
    return fit_configurations(data, units, replace(settings.cmaes, penalty=penalty), seed, theta0=theta0)


def _start_table(sharing: S.Sharing, shared: torch.Tensor) -> torch.Tensor:
    """``(K, 2)`` rows starting from the shared estimate: every row at it, a camera's residuals at 0."""
    start = shared.to(torch.float64).expand(sharing.n_rows, 2).clone()
    if sharing.name == "camera+car":
        start[sharing.rows[:, 1].cpu() != S.NO_INDEX] = 0.0  # residual rows: the camera row carries the shift
    return start


def prior_totals(truth: S.TruthDistribution, n_units: int) -> torch.Tensor:
    """``(n_units, 2)`` float64 metres: theta*'s mean total per unit, the guess that looks at no pixel.

    Every level's rows are drawn around ``truth.centre`` (a camera's residuals around 0), so each unit's total has
    mean ``truth.centre``.
    """
    return torch.tensor([float(v) for v in truth.centre], dtype=torch.float64).expand(n_units, 2).clone()


def paired_targets(data: ConfigurationSet, sharing: S.Sharing, units: S.Units, noise_level: int, run: int, seed: int,
                   truth: S.TruthDistribution) -> tuple[int, torch.Tensor, torch.Tensor]:
    """Run ``run``'s seed ``run_seed(seed, noise, run)``, its targets ``(N, H, W)`` bool (theta* drawn from ``truth``
    with that seed, rendered, then Table 2's noise of that seed) and theta*'s unit totals ``(U, 2)`` metres."""
    own_seed = run_seed(seed, noise_level, run)
    theta = S.draw_truth(sharing, own_seed, truth)
    clean = S.render_targets(data, theta, sharing.param_index)
    targets = clean if noise_level == 0 else noisy_targets(clean, noise_level, own_seed)
    return own_seed, targets, S.unit_totals(theta, units)


def objects_runs(data: ConfigurationSet, sharing: str, noise_level: int, runs: Sequence[int], seed: int,
                 settings: ObjectsSettings, n_cars: torch.Tensor | None = None,
                 methods: Sequence[str] = METHODS, progress: bool = False,
                 scan: tuple[float, float] | None = None) -> pd.DataFrame:
    """Table 6's runs of one ``sharing`` at one ``noise_level``: one record per (run, method, unit).

    Run ``r`` takes ``run_seed(seed, noise_level, r)``: it draws theta* (:func:`sdm.sharing.draw_truth`), the noise
    of the targets, SDM's shuffling and the baselines' seeds, so every method of the run sees the same targets.

    Args:
        data: the configurations (with their points' cars for the car sharings).
        sharing: one of :data:`sdm.sharing.ROW_SHARINGS` (the shared one is Table 2's runs, quoted).
        noise_level: the noise level of the targets (Table 2's), screen pixels.
        n_cars: ``(N,)`` cars per configuration (on screen, hidden or not), to count the hidden ones.
        methods: a subset of :data:`METHODS`; the :data:`REFERENCES` are always scored.
        scan: ``(reach, step)`` metres: score :data:`EXACT_SET` on the first run's units (:func:`exact_set_records`);
            ``None``: not.

    Returns:
        A DataFrame with columns ``sharing, noise_level, run, seed, method, config, car, unit, a, b, a_true, b_true,
        distance, gated, start, cpu_s, extent_a, extent_b`` (``car`` -1 for a configuration's unit; ``gated`` the
        distance after the prior gate (:func:`prior_gate`; NaN for the floor, the exact-match sets and at the
        camera+car level, where a unit is two rows); ``start`` the distance
        of the method's start on the unit, the paper's shared start for the floor and the references; ``cpu_s`` the
        run's CPU seconds per configuration with units; ``extent_a``, ``extent_b`` metres, the exact-match set's
        extent per axis on :data:`EXACT_SET`'s records, NaN on the others), and per run a row of method ``"hidden"``
        whose ``unit`` counts the cars that own no point (no row, nothing to estimate; left out of every mean).
    """


    if sharing not in S.ROW_SHARINGS:
        raise SDMInputError(f"sharing must be one of {', '.join(S.ROW_SHARINGS)}, got {sharing!r}")
    unknown = sorted(set(methods) - set(METHODS))
    if unknown:
        raise SDMInputError(f"methods must be of {', '.join(METHODS)}, got {unknown}")
    layout = S.sharing(sharing, data, n_cars=n_cars)
    units = S.units(data, layout.param_index, layout.n_rows)
    unit_car = _unit_cars(layout, units)
    owners = max(int((units.offsets[1:] > units.offsets[:-1]).sum()), 1)
    # the gate's spread per unit, where a unit is one row (not a camera + residual total)
    unit_sd = prior_sd(layout, settings.truth)[units.rows[:, -1].cpu()] if units.rows.shape[1] == 1 else None
    nan = float("nan")
    records = []
    for index, run in enumerate(tqdm(list(runs), desc=f"{sharing}, noise {noise_level}", unit="run", disable=not progress,
                                     leave=False)):
        own_seed, targets, true_totals = paired_targets(data, layout, units, noise_level, run, seed, settings.truth)
        noisy = data.with_targets(targets)
        estimates = {}
        # the paper's rule's shared start: SDM's paper-rule rows and the per-configuration baselines start there
        paper_start = shared_start(data, targets, own_seed, settings)
        for method in methods:
            if method in ("sdm_paper", "sdm_schedule"):
                paper = method == "sdm_paper"
                theta, shared, seconds, _ = sdm_rows(data, targets, layout, own_seed, settings,
                                                     None if paper else settings.schedule,
                                                     paper_start if paper else None)
                estimates[method] = (S.unit_totals(theta, units), seconds,
                                     S.unit_totals(_start_table(layout, shared), units))
            elif method in ("cmaes", "cmaes_car", "cmaes_reg", "silhouette"):
                start, shared_seconds = paper_start
                table = _start_table(layout, start)
                began = _cpu()
                if method in ("cmaes", "cmaes_car", "cmaes_reg"):
                    fit = search_units(method, noisy, units, settings, own_seed, S.unit_totals(table, units))
                    totals = fit.totals
                else:
                    result = silhouette.fit(noisy, settings.silhouette, own_seed, theta0=table,
                                            param_index=layout.param_index)
                    totals = S.unit_totals(torch.as_tensor(result.theta, dtype=torch.float64), units)
                estimates[method] = (totals, _cpu() - began + shared_seconds, S.unit_totals(table, units))
            elif method == "floor":
                began = _cpu()
                floor = floor_configurations(noisy, units, true_totals, settings.floor, own_seed,
                                             configs=_missed_by_truth(noisy, units, true_totals))
                estimates[method] = (floor.totals, _cpu() - began, None)
        start_totals = S.unit_totals(_start_table(layout, paper_start[0]), units)
        estimates["start"] = (start_totals, paper_start[1], start_totals)
        estimates["prior"] = (prior_totals(settings.truth, len(units)), 0.0, start_totals)
        for method, (totals, seconds, given) in estimates.items():
            distance = (totals - true_totals).norm(dim=1)
            # the floor is given theta* itself: its row reads against the start the others are given, ungated
            start_distance = ((start_totals if given is None else given) - true_totals).norm(dim=1)
            gated = (torch.full_like(distance, nan) if unit_sd is None or given is None else
                     (prior_gate(totals, given, unit_sd, settings.gate)[0] - true_totals).norm(dim=1))
            for u in range(len(units)):
                records.append({"sharing": sharing, "noise_level": noise_level, "run": run, "seed": own_seed, "method": method,
                                "config": int(units.config[u]), "car": int(unit_car[u]), "unit": u,
                                "a": float(totals[u, 0]), "b": float(totals[u, 1]),
                                "a_true": float(true_totals[u, 0]), "b_true": float(true_totals[u, 1]),
                                "distance": float(distance[u]), "gated": float(gated[u]),
                                "start": float(start_distance[u]), "cpu_s": seconds / owners, "extent_a": nan,
                                "extent_b": nan})
        if scan is not None and index == 0:
            sets, seconds = exact_set_records(data, layout, units, own_seed, settings.truth, scan)
            start_distance = (start_totals - true_totals).norm(dim=1)
            for u in range(len(units)):
                records.append({"sharing": sharing, "noise_level": noise_level, "run": run, "seed": own_seed, "method": EXACT_SET,
                                "config": int(units.config[u]), "car": int(unit_car[u]), "unit": u,
                                "a": nan, "b": nan, "a_true": float(true_totals[u, 0]),
                                "b_true": float(true_totals[u, 1]), "distance": float(sets.distance[u]),
                                "gated": nan, "start": float(start_distance[u]), "cpu_s": seconds / owners,
                                "extent_a": float(sets.extent[u, 0]), "extent_b": float(sets.extent[u, 1])})
        records.append({"sharing": sharing, "noise_level": noise_level, "run": run, "seed": own_seed, "method": "hidden",
                        "config": -1, "car": -1, "unit": int(layout.hidden.shape[0]), "a": 0.0, "b": 0.0,
                        "a_true": 0.0, "b_true": 0.0, "distance": 0.0, "gated": nan, "start": 0.0, "cpu_s": 0.0,
                        "extent_a": nan, "extent_b": nan})
    return pd.DataFrame.from_records(records, columns=RUN_COLUMNS)


#: The columns of :func:`objects_runs`' records.
RUN_COLUMNS = ["sharing", "noise_level", "run", "seed", "method", "config", "car", "unit", "a", "b", "a_true", "b_true",
               "distance", "gated", "start", "cpu_s", "extent_a", "extent_b"]


def _missed_by_truth(data: ConfigurationSet, units: S.Units, truth: torch.Tensor) -> list[int]:
    """The configurations with units whose target theta* does not reproduce exactly (count > 0 at ``truth``).

    Elsewhere theta* attains the least count, 0, and is the floor's answer (:func:`sdm.experiments.baselines.rows.nearest_minimiser`
    keeps theta* wherever it attains the least count): no search is needed. Without noise that is every configuration.
    """
    missed = []
    for index in range(len(data)):
        first, last = int(units.offsets[index]), int(units.offsets[index + 1])
        if last > first and int(configuration_objective(data, units, index).counts(
                truth[first:last].to(data.device).unsqueeze(0))[0]) != 0:
            missed.append(index)
    return missed


def exact_set_records(data: ConfigurationSet, sharing: S.Sharing, units: S.Units, own_seed: int,
                      truth: S.TruthDistribution, scan: tuple[float, float]):
    """The exact-match set of every unit for a run's theta* (drawn from ``own_seed`` as :func:`paired_targets` does),
    scanned on its noise-free targets with ``scan = (reach, step)`` metres (:func:`sdm.experiments.identifiability.exact_sets`).

    Returns:
        ``(sets, seconds)``: :class:`sdm.experiments.identifiability.ExactSets` over every unit and the scan's CPU seconds.
    """
    began = _cpu()
    theta = S.draw_truth(sharing, own_seed, truth)
    clean = data.with_targets(S.render_targets(data, theta, sharing.param_index))
    reach, step = scan
    sets = exact_sets(clean, units, S.unit_totals(theta, units), reach=float(reach), step=float(step))
    return sets, _cpu() - began


def _unit_cars(sharing: S.Sharing, units: S.Units) -> torch.Tensor:
    """``(U,)`` int64 the car of each unit (its last row's car; -1 for a configuration's unit)."""
    last_row = units.rows[:, -1]
    return sharing.rows[last_row, 1].cpu()


def scaling_runs(data: ConfigurationSet, n_cars: int, noise_level: int, runs: Sequence[int], seed: int,
                 settings: ObjectsSettings, epochs: Sequence[int], budgets: Sequence[int],
                 progress: bool = False, scan: tuple[float, float] | None = None) -> pd.DataFrame:
    """Error against CPU time per configuration, one row per car, for SDM and CMA-ES at several budgets.

    Images with exactly ``n_cars`` cars each (:func:`sdm.experiments.data.set_with_cars`), one row per car. SDM's rows
    (:func:`sdm_rows`: the paper's rule ``sdm_paper`` and the recommended schedule ``sdm_schedule``, each scored
    against its own shared start) run with ``n_epoch`` in ``epochs``; CMA-ES jointly (``cmaes``) and per car
    (``cmaes_car``, block sweeps) with ``evaluations_per_unknown`` in ``budgets``, from the paper's rule's shared
    start. The do-nothing references (:data:`REFERENCES`: that shared start, theta*'s mean) are scored per run with
    budget 0; with ``scan = (reach, step)`` metres, :data:`EXACT_SET` on the first run's cars
    (:func:`exact_set_records`). Every method is also scored after the prior gate (:func:`prior_gate`, from its own
    start).

    Returns:
        A DataFrame with columns ``cars, noise_level, run, method, budget, mean, median, start, closer, cpu_s, extent_a,
        extent_b, gated_mean, gated_closer`` (distances in metres over the run's cars; ``start`` the mean distance
        of the method's start over the same cars, ``closer`` the share of cars that end closer than it; ``cpu_s``
        per configuration; ``extent_a``, ``extent_b`` the median over the cars of the exact-match set's extent per
        axis, metres, on :data:`EXACT_SET`'s record, NaN on the others; ``gated_mean``, ``gated_closer`` the same
        after the prior gate, NaN on :data:`EXACT_SET`'s record).
    """
    sharing = S.sharing("car", data)
    units = S.units(data, sharing.param_index, sharing.n_rows)
    sd = prior_sd(sharing, settings.truth)
    records = []
    for index, run in enumerate(tqdm(list(runs), desc=f"{n_cars} cars", unit="run", disable=not progress,
                                     leave=False)):
        own_seed, targets, true_totals = paired_targets(data, sharing, units, noise_level, run, seed, settings.truth)
        start, shared_seconds = paper_start = shared_start(data, targets, own_seed, settings)
        start_totals = S.unit_totals(_start_table(sharing, start), units)
        start_error = start_totals - true_totals

        def record(method, budget, totals, seconds, given=start_totals):
            gated = prior_gate(totals, given, sd, settings.gate)[0]
            records.append(_scaling_record(n_cars, noise_level, run, method, budget, totals - true_totals,
                                           given - true_totals, seconds / len(data), gated - true_totals))

        record("start", 0, start_totals, shared_seconds)
        record("prior", 0, prior_totals(settings.truth, len(units)), 0.0)
        if scan is not None and index == 0:
            sets, seconds = exact_set_records(data, sharing, units, own_seed, settings.truth, scan)
            set_record = _scaling_record(n_cars, noise_level, run, EXACT_SET, 0, torch.zeros_like(start_error),
                                         start_error, seconds / len(data), None)
            set_record |= {"mean": float(sets.distance.mean()), "median": float(sets.distance.median()),
                           "closer": float((sets.distance < start_error.norm(dim=1)).to(torch.float64).mean()),
                           "extent_a": float(sets.extent[:, 0].median()),
                           "extent_b": float(sets.extent[:, 1].median())}
            records.append(set_record)
        # each scored against its rule's own shared start: the paper's is ``start``
        for method, schedule, given in (("sdm_paper", None, paper_start), ("sdm_schedule", settings.schedule, None)):
            for n_epoch in epochs:
                epoched = replace(settings, rows=replace(settings.rows, n_epoch=int(n_epoch)))
                theta, shared, seconds, _ = sdm_rows(data, targets, sharing, own_seed, epoched, schedule, given)
                record(method, n_epoch, S.unit_totals(theta, units), seconds,
                       S.unit_totals(_start_table(sharing, shared), units))
        for method in ("cmaes", "cmaes_car"):
            for budget in budgets:
                began = _cpu()
                budgeted = replace(settings, cmaes=replace(settings.cmaes, evaluations_per_unknown=int(budget)))
                fit = search_units(method, data.with_targets(targets), units, budgeted, own_seed, start_totals)
                record(method, budget, fit.totals, _cpu() - began + shared_seconds)
    return pd.DataFrame.from_records(records, columns=SCALING_COLUMNS)


#: The columns of :func:`scaling_runs`' records.
SCALING_COLUMNS = ["cars", "noise_level", "run", "method", "budget", "mean", "median", "start", "closer", "cpu_s",
                   "extent_a", "extent_b", "gated_mean", "gated_closer"]


def _scaling_record(n_cars, noise_level, run, method, budget, error, start_error, cpu_s, gated_error) -> dict:
    """One record of the scaling: ``error``, ``start_error`` and ``gated_error`` (``(U, 2)`` metres, the last after
    the prior gate, or None) over the run's cars."""
    distance, start = error.norm(dim=1), start_error.norm(dim=1)
    gated = gated_error.norm(dim=1) if gated_error is not None else None
    return {"cars": int(n_cars), "noise_level": int(noise_level), "run": int(run), "method": method, "budget": int(budget),
            "mean": float(distance.mean()), "median": float(distance.median()), "start": float(start.mean()),
            "closer": float((distance < start).to(torch.float64).mean()), "cpu_s": float(cpu_s),
            "extent_a": float("nan"), "extent_b": float("nan"),
            "gated_mean": float(gated.mean()) if gated is not None else float("nan"),
            "gated_closer": float((gated < start).to(torch.float64).mean()) if gated is not None else float("nan")}


def search_settings(warm: dict, rows: dict, schedule: str, cmaes: dict, s: int, batch_size: int,
                    lr_decay: float) -> ObjectsSettings:
    """SDM's and CMA-ES's settings per configuration from the config's ``research.objects`` ``warm``, ``rows``,
    ``schedule`` and ``cmaes`` and the ``train`` section: :class:`ObjectsSettings` without floor or silhouette
    (Table 7 runs neither; :func:`settings_from_config` adds them for Table 6)."""
    common = dict(batch_size=int(batch_size), lr_decay=float(lr_decay), zoom=0)
    return ObjectsSettings(
        warm=TrainSettings(lr=float(warm["lr"]), n_epoch=int(warm["n_epoch"]), s=int(s), **common),
        rows=TrainSettings(lr=float(rows["lr"]), n_epoch=int(rows["n_epoch"]), s=int(rows["s"]), **common),
        schedule=str(schedule), cmaes=RowsCMAESSettings(evaluations_per_unknown=int(cmaes["evaluations_per_unknown"]),
                                                        penalty=float(cmaes.get("penalty", 0.0)),
                                                        sigma0=float(cmaes.get("step", 0.3))),
        car_sigma0=float(cmaes.get("car_step", cmaes.get("step", 0.3))),
        floor=None, silhouette=None, first_zoom=str(rows.get("first_zoom", "s")))


def settings_from_sections(section: dict, train: dict) -> ObjectsSettings:
    """:func:`settings_from_config` from the config's whole ``research.objects`` section and its ``train`` section."""
    return settings_from_config(section["truth"], section["warm"], section["rows"], section["schedule"], section["cmaes"],
                                section["floor"], section["silhouette"], train["s"], section["batch_size"],
                                train["lr_decay"], section["gate"])


def settings_from_config(truth: dict, warm: dict, rows: dict, schedule: str, cmaes: dict, floor: dict,
                         silhouette: dict, s: int, batch_size: int, lr_decay: float, gate: float) -> ObjectsSettings:
    """:class:`ObjectsSettings` from the config's ``research.objects`` values and the ``train`` section."""
    return replace(
        search_settings(warm, rows, schedule, cmaes, s, batch_size, lr_decay),
        floor=RowsFloorSettings(evaluations_per_unknown=int(floor["evaluations_per_unknown"]),
                                restarts=int(floor["restarts"])),
        silhouette=SilhouetteSettings(**silhouette), gate=float(gate),
        truth=S.TruthDistribution(camera_sd=float(truth["camera_sd"]), car_sd=float(truth["car_sd"]),
                                  residual_sd=float(truth["residual_sd"])),
    )

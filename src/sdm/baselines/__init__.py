"""Table 3: SDM against the losses a researcher would use instead (issue 11).

Every method estimates the shift ``theta = (a, b)`` (metres) from the same training configurations
(points ``Q``, binary targets ``L``) through one interface::

    result = fit("chamfer", train_set, ChamferSettings(lr=0.03), seed=7)
    result.theta, result.seconds

=============  =========================================================  ==========================
name           what it minimises                                          optimiser
=============  =========================================================  ==========================
``sdm``        SDM's loss through the layer (dynamic gradient flow)       SGD, zoom levels s..0
``silhouette`` soft IoU of Gaussian-splat soft silhouettes vs the target  Adam, sigma 2^k px, k=3..0
``chamfer``    2D Chamfer distance, projected points vs target pixels     Adam, 5 lr rounds
``sinkhorn``   Sinkhorn divergence (geomloss) between the same sets       Adam, blur 2^k px, 5 rounds
``cmaes``      exact count of mismatched pixels at zoom 0 (FP + FN)       CMA-ES (pycma), 240 calls
=============  =========================================================  ==========================

Budgets: the settings' defaults are 36 / 48 / 24 Adam steps per stage on mini-batches of 16
configurations and 240 objective calls. The workflow's default config compares at equal time: on
the default 512 training configurations one SDM run of Table 2 costs about 0.64 s of one core
(level 2), and chamfer (0.59 s) and CMA-ES (0.56 s, after its grouped count) match it with these
defaults, while silhouette and sinkhorn cost 1.6 and 1.9 s, so config.yaml gives them 8
configurations a step and 27 / 16 steps per stage (0.54 and 0.65 s; their level-2 mean distance
over 10 runs moves from 11.2 to 15.1 and from 16.9 to 18.1 e-3 m). The noise runs are fitted many at a time (``fit_runs``,
:func:`noise_runs`), each run bit-identical to its single fit; on one CPU core that shares little,
for SDM (about 1.2x, docs/method.md) as for the gradient baselines, whose steps are dominated by
arithmetic on their dense per-step tensors (nearest-neighbour matrices, splatted cells, Sinkhorn
kernels) rather than by per-operation overhead (``benchmarks/bench_baselines.py`` measures both
ways; the ``seconds_per_run`` of Table 3 is the batched cost).

:func:`tune` scores a grid of settings by the dev loss of Table 1 (:func:`sdm.metrics.dev_loss`:
mean false-positive pixels per dev configuration at ``theta``), so every method is picked by the
same criterion as SDM; :func:`noise_run` is :func:`sdm.experiments.noise_run` for any method:
the same run seeds, hence the same noisy targets (paired comparison).

``geomloss`` and ``cma`` are imported only when their method runs: they are dependencies of the
workflow's baseline stage, not of the ``sdm`` library.
"""
from __future__ import annotations

import itertools
from dataclasses import asdict, dataclass
from typing import Any, Callable, Mapping, Sequence

import pandas as pd

from ..batch import ConfigurationSet
from ..camera import Camera
from ..errors import SDMInputError
from ..experiments import noisy_targets, run_seed
from ..metrics import dev_loss, distance
from ..sky import SKY_SHIFT
from . import chamfer, cmaes, sdm_layer, silhouette, sinkhorn
from .chamfer import ChamferSettings
from .cmaes import CMAESSettings
from .common import FitResult
from .silhouette import SilhouetteSettings
from .sinkhorn import SinkhornSettings
from .sdm_layer import SDMSettings


@dataclass(frozen=True)
class Method:
    """A registered method.

    Attributes:
        name: registry key (config and file names).
        label: how tables and figures name it.
        settings: its settings dataclass.
        fit: ``fit(train_set, settings, seed, camera, theta0) -> FitResult``.
        requires: the extra package it imports when it runs (``None``: only torch).
        fit_runs: ``fit_runs(train_sets, settings, seeds, camera, theta0) -> list[FitResult]``: many
            independent runs as one program, run ``r`` equal to ``fit(train_sets[r], settings,
            seeds[r])``; ``None`` when the method has none (:func:`noise_runs` then loops over ``fit``).
    """

    name: str
    label: str
    settings: type
    fit: Callable[..., FitResult]
    requires: str | None = None
    fit_runs: Callable[..., list[FitResult]] | None = None


METHODS: dict[str, Method] = {
    "sdm": Method("sdm", "SDM (ours, Table 2)", SDMSettings, sdm_layer.fit, fit_runs=sdm_layer.fit_runs),
    "silhouette": Method("silhouette", "soft silhouette (soft IoU)", SilhouetteSettings, silhouette.fit,
                         fit_runs=silhouette.fit_runs),
    "chamfer": Method("chamfer", "2D Chamfer", ChamferSettings, chamfer.fit, fit_runs=chamfer.fit_runs),
    "sinkhorn": Method("sinkhorn", "Sinkhorn OT (geomloss)", SinkhornSettings, sinkhorn.fit, "geomloss",
                       fit_runs=sinkhorn.fit_runs),
    # CMA-ES is batched in its own module on another branch: registered when that branch is merged.
    "cmaes": Method("cmaes", "CMA-ES on pixel mismatch", CMAESSettings, cmaes.fit, "cma",
                    fit_runs=getattr(cmaes, "fit_runs", None)),
}


def method(name: str, key: str = "method") -> Method:
    """The registered method ``name``; :class:`SDMInputError` naming ``key`` if there is none."""
    if name not in METHODS:
        raise SDMInputError(f"config key '{key}': unknown method {name!r}; known: {', '.join(METHODS)}")
    return METHODS[name]


def make_settings(name: str, values: Mapping[str, Any] | None = None, key: str | None = None):
    """Settings of method ``name`` from a mapping (e.g. a config section), defaults for missing keys.

    Raises:
        SDMInputError: for an unknown method, an unknown key or a bad value, naming the config
            key ``<key>.<field>`` (``key`` defaults to ``baselines.<name>``).
    """
    key = key or f"baselines.{name}"
    entry = method(name, key)
    values = dict(values or {})
    known = set(entry.settings.__dataclass_fields__)
    unknown = sorted(set(values) - known)
    if unknown:
        raise SDMInputError(f"config key '{key}.{unknown[0]}': not a setting of {name!r}; known: {sorted(known)}")
    try:
        return entry.settings(**values)
    except SDMInputError as error:
        field = getattr(error, "field", None)
        if field is None:  # SDM's own TrainSettings names the field at the start of its message
            field = next((f for f in sorted(known, key=len, reverse=True) if str(error).startswith(f)), None)
        if field is None:
            raise SDMInputError(f"config key '{key}': {error}") from None
        problem = getattr(error, "problem", str(error))
        raise SDMInputError(f"config key '{key}.{field}': {problem}") from None


def grid(name: str, base: Mapping[str, Any] | None = None, cells: Mapping[str, Sequence] | None = None,
         key: str | None = None) -> list:
    """The tuning grid: settings for every combination of ``cells`` (field -> values) over ``base``.

    Fields vary in the order given, the last fastest. An empty ``cells`` gives ``[base]``.
    """
    key = key or f"baselines.{name}"
    cells = dict(cells or {})
    for field, values in cells.items():
        if isinstance(values, (str, bytes)) or not isinstance(values, Sequence) or len(values) == 0:
            raise SDMInputError(f"config key '{key}.{field}': must be a non-empty list, got {values!r}")
    combos = itertools.product(*cells.values()) if cells else [()]
    return [make_settings(name, dict(base or {}) | dict(zip(cells, combo)), key) for combo in combos]


def settings_grid(name: str, section: Mapping[str, Any] | None = None, key: str | None = None) -> list:
    """The tuning grid from one config section: a list value is a grid axis, a scalar is fixed.

    ``{"lr": [0.1, 0.3], "sigma": [0.5, 1.0], "steps": 12}`` gives four cells, each with 12 steps.
    Errors name ``<key>.<field>`` (``key`` defaults to ``baselines.<name>``).
    """
    key = key or f"baselines.{name}"
    section = dict(section or {})
    axes = {field: value for field, value in section.items() if isinstance(value, (list, tuple))}
    fixed = {field: value for field, value in section.items() if field not in axes}
    return grid(name, fixed, axes, key)


def fit(name: str, train_set: ConfigurationSet, settings=None, seed: int = 0, camera: Camera | None = None,
        theta0: Sequence[float] = (0.0, 0.0)) -> FitResult:
    """Estimate ``theta`` with method ``name`` (default settings when ``settings`` is None)."""
    entry = method(name)
    settings = entry.settings() if settings is None else settings
    if not isinstance(settings, entry.settings):
        raise SDMInputError(f"settings for {name!r} must be {entry.settings.__name__}, got {type(settings).__name__}")
    return entry.fit(train_set, settings, seed=int(seed), camera=camera, theta0=tuple(theta0))


def tune(name: str, train_set: ConfigurationSet, dev_set: ConfigurationSet, settings: Sequence, seed: int = 0,
         s: int = 4, shift: Sequence[float] = SKY_SHIFT, camera: Camera | None = None) -> pd.DataFrame:
    """Fit every grid cell on the (noise-free) training set and score it on the dev set.

    Args:
        settings: the cells (:func:`grid`).
        seed: the fits' seed (as Table 1's ``train.seed``).
        s: SDM's chain for the dev loss (Table 1's criterion).

    Returns:
        One row per cell: ``method, cell``, the settings' fields, ``dev_loss`` (mean false-positive
        pixels per dev configuration), ``a, b, distance`` (metres; reported, not used to choose),
        ``seconds, evaluations``, and ``best`` (lowest dev loss, first on ties).
    """
    rows = []
    for cell, cell_settings in enumerate(settings):
        result = fit(name, train_set, cell_settings, seed, camera)
        rows.append({"method": name, "cell": cell} | asdict(cell_settings) | {
            "dev_loss": float(dev_loss(dev_set, result.theta, s=s, camera=camera)),
            "a": result.theta[0], "b": result.theta[1],
            "distance": distance(result.theta, tuple(shift)),
            "seconds": result.seconds, "evaluations": result.evaluations,
        })
    frame = pd.DataFrame.from_records(rows)
    frame["best"] = False
    frame.loc[int(frame["dev_loss"].idxmin()), "best"] = True
    return frame


def best_settings(name: str, tuning: pd.DataFrame):
    """The settings of the best row of a :func:`tune` frame (or of its CSV)."""
    entry = method(name)
    chosen = tuning[tuning["best"].astype(bool)]
    if len(chosen) != 1:
        raise SDMInputError(f"tuning of {name!r}: expected one best cell, found {len(chosen)}")
    row = chosen.iloc[0]
    values = {}
    for field in entry.settings.__dataclass_fields__:
        value = row[field]
        default = getattr(entry.settings(), field)
        values[field] = type(default)(value) if not isinstance(default, str) else str(value)
    return entry.settings(**values)


RUN_COLUMNS = ["method", "level", "run", "seed", "a", "b", "distance", "seconds", "evaluations"]


def noise_run(name: str, train_set: ConfigurationSet, level: int, run: int, settings, seed: int,
              shift: Sequence[float] = SKY_SHIFT, camera: Camera | None = None) -> dict:
    """One paired robustness run: Table 2's noisy targets for ``(seed, level, run)``, then ``fit``.

    The run's seed (:func:`sdm.experiments.run_seed`) draws the noise exactly as Table 2's run
    does and seeds the method (mini-batches, subsampling, CMA-ES).

    Returns:
        ``{"method", "level", "run", "seed", "a", "b", "distance", "seconds", "evaluations"}``
        (metres, seconds; ``seconds`` is the fit alone, without drawing the noise).
    """
    seed_run = run_seed(seed, level, run)
    noisy = train_set.with_targets(noisy_targets(train_set.targets, level, seed_run))
    result = fit(name, noisy, settings, seed_run, camera)
    a, b = result.theta
    return {"method": name, "level": int(level), "run": int(run), "seed": seed_run, "a": float(a), "b": float(b),
            "distance": distance((a, b), tuple(shift)), "seconds": result.seconds, "evaluations": result.evaluations}


def noise_runs(name: str, train_set: ConfigurationSet, level: int, runs: Sequence[int], settings, seed: int,
               shift: Sequence[float] = SKY_SHIFT, camera: Camera | None = None,
               group_size: int | None = None) -> pd.DataFrame:
    """Several :func:`noise_run` at one level, one row each (columns :data:`RUN_COLUMNS`).

    A method with ``fit_runs`` fits the runs ``group_size`` at a time as one program (row for row
    what :func:`noise_run` gives, ``tests/test_baselines_batched.py`` holds it); its ``seconds`` is
    then the group's wall time over the group's runs. Other methods run one :func:`noise_run` each.

    Args:
        group_size: runs fitted together; default all of ``runs``. Memory grows with it: each run of
            the group holds its noisy targets (``N x H x W`` bool, 16.8 MB for 512 configurations of
            128 x 256) and, for ``silhouette``/``sdm``, their zoom pyramid (about 6 MB more).
    """
    entry = method(name)
    runs = [int(run) for run in runs]
    if entry.fit_runs is None or not runs:
        rows = [noise_run(name, train_set, level, run, settings, seed, shift, camera) for run in runs]
        return pd.DataFrame.from_records(rows, columns=RUN_COLUMNS)
    group_size = len(runs) if group_size is None else group_size
    if isinstance(group_size, bool) or int(group_size) != group_size or group_size < 1:
        raise SDMInputError(f"group_size must be a positive integer, got {group_size!r}")
    settings = entry.settings() if settings is None else settings
    if not isinstance(settings, entry.settings):
        raise SDMInputError(f"settings for {name!r} must be {entry.settings.__name__}, got {type(settings).__name__}")
    seeds = [run_seed(seed, level, run) for run in runs]
    active = train_set.targets.nonzero() if level else None  # every run moves the same clean pixels
    rows = []
    for first in range(0, len(runs), int(group_size)):
        group = range(first, min(first + int(group_size), len(runs)))
        noisy = [train_set.with_targets(noisy_targets(train_set.targets, level, seeds[i], active)) for i in group]
        results = entry.fit_runs(noisy, settings, [seeds[i] for i in group], camera=camera)
        del noisy
        for i, result in zip(group, results):
            a, b = result.theta
            rows.append({"method": name, "level": int(level), "run": runs[i], "seed": seeds[i], "a": float(a),
                         "b": float(b), "distance": distance((a, b), tuple(shift)), "seconds": result.seconds,
                         "evaluations": result.evaluations})
    return pd.DataFrame.from_records(rows, columns=RUN_COLUMNS)


__all__ = [
    "METHODS", "Method", "FitResult", "SDMSettings", "SilhouetteSettings", "ChamferSettings", "SinkhornSettings",
    "CMAESSettings", "RUN_COLUMNS", "best_settings", "fit", "grid", "make_settings", "method", "noise_run",
    "noise_runs", "settings_grid", "tune",
]

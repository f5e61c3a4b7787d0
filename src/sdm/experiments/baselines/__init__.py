"""Table 3: SDM against the losses a researcher would use instead.

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
:func:`baseline_noise_runs`), each run bit-identical to its single fit; on one CPU core that shares little,
for SDM (about 1.2x, docs/method/fast-path.md) as for the gradient baselines, whose steps are dominated by
arithmetic on their dense per-step tensors (nearest-neighbour matrices, splatted cells, Sinkhorn
kernels) rather than by per-operation overhead (``benchmarks/speed/bench_baselines.py`` measures both
ways; the ``seconds_per_run`` of Table 3 is the batched cost).

:func:`tune` scores a grid of settings by the dev loss of Table 1 (:func:`sdm.metrics.dev_loss`:
mean false-positive pixels per dev configuration at ``theta``), so every method is picked by the
same criterion as SDM; :func:`baseline_noise_runs` runs Table 2's runs (:func:`sdm.experiments.paired_runs`)
for any method: the same run seeds, hence the same noisy targets (paired comparison).

``geomloss`` and ``cma`` are imported only when their method runs: they are dependencies of the
workflow's baseline stage, not of the ``sdm`` library.
"""
from __future__ import annotations

import itertools
from dataclasses import asdict, dataclass
from typing import Any, Callable, Mapping, Sequence

import pandas as pd

from ...batch import ConfigurationSet
from ...camera import Camera
from ...errors import SDMInputError
from ... import experiments
from ..runs import NOISE_GROUP_SIZE, paired_runs, shift_record
from ...metrics import dev_loss, distance
from ...sky import SKY_SHIFT
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
            seeds[r])``; ``None`` when the method has none (:func:`baseline_noise_runs` then loops over ``fit``).
        group_size: runs :func:`baseline_noise_runs` hands ``fit_runs`` at a time by default; ``None``: all the
            runs of the call (the baselines' dense steps share nothing across groups).
    """

    name: str
    label: str
    settings: type
    fit: Callable[..., FitResult]
    requires: str | None = None
    fit_runs: Callable[..., list[FitResult]] | None = None
    group_size: int | None = None


METHODS: dict[str, Method] = {
    # SDM's runs in Table 2's groups (sdm.experiments.NOISE_GROUP_SIZE: the memory/speed trade-off).
    "sdm": Method("sdm", "SDM (ours, Table 2)", SDMSettings, sdm_layer.fit, fit_runs=sdm_layer.fit_runs,
                  group_size=NOISE_GROUP_SIZE),
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
    return entry.fit(train_set, _checked_settings(entry, settings), seed=int(seed), camera=camera,
                     theta0=tuple(theta0))


def _checked_settings(entry: Method, settings):
    """``settings`` for ``entry`` (its defaults when ``None``); :class:`SDMInputError` if of another method."""
    settings = entry.settings() if settings is None else settings
    if not isinstance(settings, entry.settings):
        raise SDMInputError(f"settings for {entry.name!r} must be {entry.settings.__name__}, "
                            f"got {type(settings).__name__}")
    return settings


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


#: Columns of Table 3's run rows (:func:`baseline_noise_runs`): the method, Table 2's columns
#: (:data:`sdm.experiments.RUN_COLUMNS`), the fit's ``seconds`` and its loss ``evaluations``.
RUN_COLUMNS = ["method", *experiments.RUN_COLUMNS, "seconds", "evaluations"]


def baseline_noise_runs(name: str, train_set: ConfigurationSet, noise_level: int, runs: Sequence[int], settings, seed: int,
               shift: Sequence[float] = SKY_SHIFT, camera: Camera | None = None,
               group_size: int | None = None) -> pd.DataFrame:
    """Table 3's paired robustness runs of method ``name`` at one level, one row each (:data:`RUN_COLUMNS`).

    Run ``r`` is Table 2's run ``(level, r)`` (:func:`sdm.experiments.paired_runs`: the seed
    :func:`sdm.experiments.run_seed` ``(seed, level, r)``, which draws the same noisy targets as
    Table 2's run and seeds the method: mini-batches, subsampling, CMA-ES), fitted by the method's
    ``fit_runs`` ``group_size`` runs at a time as one program (each run what ``fit`` gives it alone,
    ``tests/baselines/test_baselines_batched.py``), or by one ``fit`` per run for a method without ``fit_runs``.
    ``seconds`` is the fit alone, without drawing the noise: a ``fit_runs`` group's wall time over
    its runs.

    Args:
        settings: the method's settings (``None``: its defaults).
        seed: the experiment's noise seed (as ``noise.seed`` for Table 2).
        group_size: runs fitted together; default the method's ``group_size`` (``None``: all of
            ``runs``). Memory grows with it: each run of the group holds its noisy targets (``N x H x W``
            bool, 16.8 MB for 512 configurations of 128 x 256) and, for ``silhouette``/``sdm``, their
            zoom pyramid (about 6 MB more).
    """
    entry = method(name)
    settings = _checked_settings(entry, settings)
    group_size = entry.group_size if group_size is None else group_size

    def fit_group(targets, seeds) -> list[FitResult]:
        sets = [train_set.with_targets(run_targets) for run_targets in targets]
        if entry.fit_runs is None:
            return [entry.fit(data, settings, seed=seed_run, camera=camera, theta0=(0.0, 0.0))
                    for data, seed_run in zip(sets, seeds)]
        return entry.fit_runs(sets, settings, seeds, camera=camera)

    def record(result: FitResult) -> dict:
        return {"method": name} | shift_record(result.theta, shift) | {"seconds": result.seconds,
                                                                       "evaluations": result.evaluations}

    return paired_runs(train_set.targets, noise_level, runs, seed, fit_group, record, RUN_COLUMNS, group_size)


__all__ = [
    "METHODS", "Method", "FitResult", "SDMSettings", "SilhouetteSettings", "ChamferSettings", "SinkhornSettings",
    "CMAESSettings", "RUN_COLUMNS", "best_settings", "fit", "grid", "make_settings", "method", "baseline_noise_runs",
    "settings_grid", "tune",
]

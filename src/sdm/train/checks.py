"""The one check of a training call's arguments (:func:`checked_runs`, shared by :func:`sdm.train.train_runs` and
:func:`sdm.train.refine_runs`) and of its result (:func:`check_divergence`): :class:`~sdm.errors.SDMInputError`
naming the argument, the run and the step (docs/library.md, "Divergence").
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from ..batch import ConfigurationSet
from ..camera import Camera
from ..errors import SDMInputError
from ..mapping.layer import METHODS
from ..sharing import check_param_index, point_shifts
from ..zoom import check_divisible
from .settings import THETA_BOUND, TrainSettings


@dataclass
class Runs:
    """The arguments of :func:`train_runs` (and :func:`refine_runs`) after :func:`checked_runs`."""

    train_set: ConfigurationSet  # on the training device
    settings: list[TrainSettings]
    common: TrainSettings  # settings[0]: every field but seed is every run's
    camera: Camera
    own_targets: list[bool]  # run r trains on the set's own targets
    rows: torch.Tensor | None  # the checked (P, G) param_index
    starts: torch.Tensor  # (R, 2), (R, 3) with fit_depth, (R, K, 2) with rows; float64 on the device
    row_rate: torch.Tensor | None  # (K,) float64 on the device


def checked_runs(train_set, targets, settings, camera, device, theta0, method, param_index, row_rate) -> Runs:
    """The one check of the runs' arguments, shared by :func:`train_runs` and :func:`refine_runs`: what one
    accepts, the other does. :class:`SDMInputError` naming the argument (see :func:`train_runs`)."""
    settings = list(settings)
    n_runs = len(settings)
    if n_runs == 0 or len(targets) != n_runs:
        raise SDMInputError(f"targets: one target set per run is needed: {len(targets)} target sets, "
                            f"{n_runs} settings")
    if not all(isinstance(one, TrainSettings) for one in settings):
        raise SDMInputError(f"settings must be TrainSettings, got {sorted({type(one).__name__ for one in settings})}")
    shared = {replace(one, seed=0) for one in settings}
    if len(shared) != 1:
        raise SDMInputError(f"settings: the runs' settings may differ only in seed, got {sorted(map(str, shared))}")
    common = settings[0]
    if method not in METHODS:
        raise SDMInputError(f"method must be one of {sorted(METHODS)}, got {method!r}")
    if method == "dense" and n_runs > 1:
        raise SDMInputError(f"method 'dense' (the grid reference) trains one run at a time, got {n_runs} runs")
    camera = camera or train_set.camera
    own_targets = [run_targets is train_set.targets for run_targets in targets]  # before the set moves
    if device is not None:
        train_set = train_set.to(usable_device(device))
    device = train_set.device
    check_divisible(camera.screen_shape, common.s)  # before anything is zoomed out
    n_configs, batch_size = len(train_set), common.batch_size
    if n_configs < batch_size:
        raise SDMInputError(f"the training set has {n_configs} configurations, fewer than one batch of {batch_size}")
    for run, run_targets in enumerate(targets):
        if (not isinstance(run_targets, torch.Tensor) or tuple(run_targets.shape) != tuple(train_set.targets.shape)
                or run_targets.dtype != torch.bool):
            raise SDMInputError(f"targets[{run}] must be bool of shape {tuple(train_set.targets.shape)}, got "
                                f"{getattr(run_targets, 'dtype', type(run_targets).__name__)} "
                                f"{tuple(getattr(run_targets, 'shape', ()))}")
    rows = None if param_index is None else check_param_index(param_index, train_set, theta0_rows(theta0))
    if rows is not None and (common.fit_depth or method == "dense"):
        raise SDMInputError("param_index: parameters attached to points train the shift (a, b) with method 'fast'; "
                            f"got fit_depth={common.fit_depth}, method={method!r}")
    starts = checked_starts(theta0, n_runs, common.fit_depth, device, n_rows=None if rows is None else int(rows.max()) + 1)
    beyond = (starts.abs().reshape(n_runs, -1) > THETA_BOUND).any(1)
    if bool(beyond.any()):
        run = int(beyond.nonzero()[0])
        raise SDMInputError(f"theta0[{run}] lies beyond the bound of {THETA_BOUND} m per component (THETA_BOUND): "
                            f"{starts[run].tolist()} is no start the flow can correct")
    for run, run_targets in enumerate(targets):
        # (a set without points trains to zero) The bytes' max: exact for bool, and ten times cheaper than any().
        if train_set.points.shape[0] and not (run_targets.numel() and bool(run_targets.view(torch.uint8).max())):
            raise SDMInputError(f"targets[{run}] holds no active pixel: the flow vanishes for every point of run {run}")
    runs = Runs(train_set, settings, common, camera, own_targets, rows, starts, checked_row_rate(row_rate, rows, device))
    check_on_screen(runs, starts.cpu(), "theta0", "its start")
    return runs


def check_divergence(thetas: torch.Tensor, theta_steps: torch.Tensor, step_rates: torch.Tensor, runs: Runs) -> None:
    """:class:`SDMInputError` naming the run, the step and the setting to change where a run diverged: its last theta
    lies beyond :data:`THETA_BOUND` (named with the step from which it stayed beyond), or every point of its set is
    off the screen at its last theta. (A theta beyond the bound in between is no error: at the tuning grid's
    largest rate the first steps overshoot by metres and come back.)

    ``thetas`` ``(records, R, ...)`` CPU float64, recorded after ``theta_steps`` steps; ``step_rates`` ``(steps,)``
    the learning rate of each step."""
    beyond = (thetas.abs().reshape(thetas.shape[0], thetas.shape[1], -1) > THETA_BOUND).any(2)  # (records, R)
    if bool(beyond[-1].any()):  # early steps may overshoot and come back: the result is what is bounded
        run = int(beyond[-1].nonzero()[0])
        within = (~beyond[:, run]).nonzero()
        record = int(within[-1]) + 1 if within.numel() else 0  # the record from which it stayed beyond
        step = int(theta_steps[record])
        rate = float(step_rates[max(step - 1, 0)]) if step_rates.numel() else float("nan")
        setting = "lr" if runs.row_rate is None else "lr or row_rate"
        raise SDMInputError(f"theta of run {run} ended beyond the bound of {THETA_BOUND} m per component "
                            f"(THETA_BOUND), where it stayed from step {step} (rate {rate!r}) on: the run diverged; "
                            f"lower {setting}")
    check_on_screen(runs, thetas[-1], "theta", f"step {int(theta_steps[-1])}")


def check_on_screen(runs: Runs, theta: torch.Tensor, name: str, when: str) -> None:
    """:class:`SDMInputError` naming ``name`` where some run's every point is off the screen at ``theta`` (``(R, 2)``,
    ``(R, 3)`` or ``(R, K, 2)`` CPU float64, metres): no point of it can land, so its flow vanishes.

    Each run's first point of every configuration is tried first: where one of them lands, so does a point of the
    run, and only a run none of them lands for is tried on every point (the same answer at a fraction of the cost).
    """
    points = runs.train_set.points.detach().to("cpu", torch.float64)
    if points.shape[0] == 0:  # a set without points trains to zero
        return
    rows = None if runs.rows is None else runs.rows.cpu()
    firsts = runs.train_set.offsets[:-1].cpu()[runs.train_set.counts.cpu() > 0]
    probe = (points[firsts], None if rows is None else rows[firsts])
    height, width = runs.camera.screen_shape
    for run in range(theta.shape[0]):
        lands = any_on_screen(*probe, theta[run], runs.camera) or any_on_screen(points, rows, theta[run],
                                                                                runs.camera)
        if not lands:
            raise SDMInputError(f"{name}: every point of run {run} is off the {height} x {width} screen at {when} "
                                f"(theta {theta[run].tolist()}): the flow vanishes; start closer or lower lr")


def any_on_screen(points: torch.Tensor, rows: torch.Tensor | None, theta: torch.Tensor, camera: Camera) -> bool:
    """Whether any of ``points`` ``(P, 3)`` moved by ``theta`` (by their ``rows``' sum of it, ``(P, G)``, where given)
    lands on ``camera``'s screen."""
    if rows is None:
        shift = torch.nn.functional.pad(theta, (0, 3 - theta.shape[-1]))
    else:
        shift = torch.nn.functional.pad(point_shifts(theta, rows), (0, 1))
    moved = points + shift
    screen = camera.project(moved[moved[:, 2] > 0], validate=False)
    height, width = camera.screen_shape
    return bool(((screen[:, 0] >= 0) & (screen[:, 0] < height) & (screen[:, 1] >= 0) & (screen[:, 1] < width)).any())


def theta0_rows(theta0) -> int | None:
    """The rows ``K`` of the first start of ``theta0`` where it has that shape (``(K, 2)``), else ``None``: then the
    index's own count, and the starts are checked against it (:func:`checked_starts`)."""
    if theta0 is None or len(theta0) == 0:
        return None
    first = torch.as_tensor(theta0[0])
    return int(first.shape[0]) if first.dim() == 2 and first.shape[0] > 0 else None


def _per_row(name: str, value, rows, what: str) -> tuple[torch.Tensor, int]:
    """``value`` as a tensor and ``K``, the rows of the checked ``rows``; :class:`SDMInputError` naming ``name``
    where there are no rows (``what`` the argument does with them) or ``value`` is not one entry per row."""
    if rows is None:
        raise SDMInputError(f"{name} needs param_index ({what})")
    n_rows = int(rows.max()) + 1
    tensor = torch.as_tensor(value)
    if tensor.shape != (n_rows,):
        raise SDMInputError(f"{name} must hold one entry per row of param_index ({n_rows}), got {tensor.dtype} "
                            f"{tuple(tensor.shape)}")
    return tensor, n_rows


def checked_row_rate(row_rate, rows, device) -> torch.Tensor | None:
    """``row_rate`` checked against the checked ``rows``: ``(K,)`` float64 on ``device``, or ``None``."""
    if row_rate is None:
        return None
    rate, n_rows = _per_row("row_rate", row_rate, rows, "it scales the rows' rates")
    if not rate.is_floating_point() or not bool((torch.isfinite(rate) & (rate > 0)).all()):
        raise SDMInputError(f"row_rate must be {n_rows} positive finite numbers (one per row of param_index), got "
                            f"{rate.dtype} {tuple(rate.shape)}")
    return rate.to(dtype=torch.float64, device=device)


def checked_row_zoom(row_zoom, rows, common: TrainSettings) -> torch.Tensor | None:
    """``row_zoom`` checked against the checked ``rows`` and the schedule's zooms ``common.s .. common.zoom``:
    ``(K,)`` int64 on the CPU, or ``None``."""
    if row_zoom is None:
        return None
    first, n_rows = _per_row("row_zoom", row_zoom, rows, "it names each row's first zoom")
    if first.is_floating_point() or first.is_complex() or first.dtype == torch.bool:
        raise SDMInputError(f"row_zoom must be {n_rows} integers (one per row of param_index), got {first.dtype} "
                            f"{tuple(first.shape)}")
    first = first.to("cpu", torch.int64)
    if n_rows and not bool(((first >= common.zoom) & (first <= common.s)).all()):
        raise SDMInputError(f"row_zoom must lie in the schedule's zooms {common.zoom} .. {common.s}, got "
                            f"{int(first.min())} .. {int(first.max())}")
    return first


def usable_device(device: torch.device | str) -> torch.device:
    """``device`` as a :class:`torch.device`; :class:`SDMInputError` naming it where this torch cannot use it."""
    try:
        device = torch.device(device)
        torch.empty(0, device=device)  # e.g. "cuda" on a CPU-only torch: an AssertionError inside torch
    except (AssertionError, RuntimeError, TypeError, ValueError) as error:
        raise SDMInputError(f"device {str(device)!r} is not available to this torch: {error}") from None
    return device


def checked_starts(theta0, n_runs: int, fit_depth: bool, device: torch.device, n_rows: int | None = None) -> torch.Tensor:
    """``(R, 2)`` (``(R, 3)`` with ``fit_depth``, ``(R, K, 2)`` with ``n_rows = K``) float64 starts on
    ``device``; zeros for ``None``."""
    n_params = 3 if fit_depth else 2
    if theta0 is None:
        shape = (n_runs, n_params) if n_rows is None else (n_runs, n_rows, 2)
        return torch.zeros(shape, dtype=torch.float64, device=device)
    if n_rows is not None:
        if len(theta0) != n_runs:
            raise SDMInputError(f"theta0 must hold one start per run ({n_runs}), got {len(theta0)}")
        starts = [torch.as_tensor(one, dtype=torch.float64, device="cpu") for one in theta0]
        for run, start in enumerate(starts):
            if start.shape != (n_rows, 2) or not bool(torch.isfinite(start).all()):
                raise SDMInputError(f"theta0[{run}] must be ({n_rows}, 2) finite numbers (one (a, b) per row of "
                                    f"param_index), got shape {tuple(start.shape)}")
        return torch.stack(starts).to(device)
    if len(theta0) != n_runs:
        raise SDMInputError(f"theta0 must hold one start per run ({n_runs}), got {len(theta0)}")
    starts = []
    for run, one in enumerate(theta0):
        start = torch.as_tensor(one, dtype=torch.float64, device="cpu").to(device)
        if fit_depth and start.shape == (2,):  # (a, b) -> (a, b, 0)
            start = torch.nn.functional.pad(start, (0, 1))
        if start.shape != (n_params,) or not bool(torch.isfinite(start).all()):
            where = "theta0" if n_runs == 1 else f"theta0[{run}]"
            raise SDMInputError(f"{where} must be {n_params} finite numbers, got {one!r}")
        starts.append(start)
    return torch.stack(starts)

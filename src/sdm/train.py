"""Training: SGD on the shift theta = (a, b) through the SDM layer (paper, section 6; docs/method/paper.md, "Training and evaluation").

theta starts at (0, 0). For zoom level ``s, s-1, ..., zoom``: ``n_epoch`` passes
over the training set in shuffled mini-batches of 16 configurations (the
incomplete last batch is dropped), the loss taken at that level; the learning
rate halves after each level. The loss is the *sum* over all points of the
batch, which is what the paper's learning rates assume.

One engine, :func:`train_runs`, trains ``R`` independent runs (own targets, seed
and start each); :func:`train` is it with ``R = 1``. On the CPU, for a rule with a compiled form
(:attr:`sdm.mapping.rules.Rule.compiled`: ``"paper"``, ``"closed_centred_r1"``, ``"group_crossing"``) on
float64 points, the whole run (every level, epoch, mini-batch, chain, flow and SGD step) is one call of the compiled kernel
(:func:`sdm.mapping.native.train_program`); everything else, and every device,
runs the torch path, one layer call per step with autograd. Both give the theta
history of the single-run loop kept in ``tests/train_reference.py`` to the bit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
import torch
from tqdm.std import tqdm  # plain text: renders in notebooks without ipywidgets, no IProgress warning

from .batch import ConfigurationSet, PointBatch
from .camera import Camera
from .errors import SDMInputError
from .mapping import SpatialDomainMapping, native
from .mapping.layer import METHODS
from .mapping.crossing import CROSSING_WIDTH, check_crossing_width
from .mapping.rules import RULES, KernelFlow, Rule, crossing_width_rule
from .sharing import check_param_index, point_shifts
from .sky import shift_vector
from .zoom import check_divisible, target_pyramid


#: The largest shift a run may start from or end at, metres per component of theta (docs/library.md,
#: "Divergence"). The paper's shift is 0.6 m long and Table 6 draws rows 0.15 m apart; a shift of 10 m moves a car
#: 20 m away by a third of the 256-pixel screen (fx * cols_per_image_pixel = 174 pixels per unit of x / z).
#: A theta beyond it is no estimate but a run that diverged (a learning rate too large) or a start the flow
#: cannot correct.
THETA_BOUND = 10.0


@dataclass(frozen=True)
class TrainSettings:
    """Hyper-parameters of one training run.

    Attributes:
        lr: initial learning rate (metres per unit of summed flow).
        n_epoch: passes over the training set per zoom level.
        batch_size: configurations per mini-batch.
        s: coarsest zoom level (blocks of ``2^s`` pixels).
        zoom: finest level trained (0 = full resolution).
        lr_decay: factor applied to the learning rate after each level.
        seed: seeds the shuffling.
        flow: the gradient rule: a name of :data:`sdm.RULES` (default ``"paper"``, eq. 19), a :class:`sdm.Rule`
            (trained by the compiled kernel where it has a compiled form) or a flow function (the torch path).
        fit_depth: train the general shift ``(a, b, c)`` with the depth flow of :mod:`sdm.depth`
            (beyond the paper); theta, its history and ``final_theta`` then have three entries.
        depth_lr_scale: the learning rate of ``c`` relative to ``lr`` (with ``fit_depth``); 20 by a
            measured sweep (1: c lags, 10-30: within 1e-2 m, 100: diverges; docs/method/depth.md).
        depth_zoom: the finest zoom level at which ``c`` moves (with ``fit_depth``; at least the coarsest
            level ``s``): the finer levels train ``(a, b)`` with ``c`` held. Default 1: at full resolution
            the pull on ``c`` with ``depth_lr_scale`` 20 walks along the near-degenerate direction of
            ``(b, c)`` (every point lies below the principal point) and leaves ``b`` off by about 2e-3 m
            at c = -1 m (measured; docs/method/depth.md).
    """

    lr: float = 3e-4
    n_epoch: int = 1
    batch_size: int = 16
    s: int = 4
    zoom: int = 0
    lr_decay: float = 0.5
    seed: int = 0
    flow: str | Rule = "paper"
    fit_depth: bool = False
    depth_lr_scale: float = 20.0
    depth_zoom: int = 1

    def __post_init__(self) -> None:
        from numbers import Integral, Real

        # Every field's type first, by name: a string would fail inside math.isfinite with a TypeError
        # naming no field, and a bool would pass as the number 0 or 1 (bool is an int subclass).
        for name in ("lr", "lr_decay", "depth_lr_scale"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, Real):
                raise SDMInputError(f"{name} must be a number, got {value!r} ({type(value).__name__})")
        for name in ("n_epoch", "batch_size", "s", "zoom", "seed", "depth_zoom"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, Integral):  # 2.0 is refused: an epoch count is exact
                raise SDMInputError(f"{name} must be an integer, got {value!r} ({type(value).__name__})")
        if not isinstance(self.fit_depth, bool):
            raise SDMInputError(f"fit_depth must be True or False, got {self.fit_depth!r}")
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise SDMInputError(f"lr must be a positive finite number, got {self.lr!r}")
        for name in ("n_epoch", "batch_size"):
            value = getattr(self, name)
            if int(value) != value or value < 1:
                raise SDMInputError(f"{name} must be a positive integer, got {value!r}")
        if int(self.s) != self.s or self.s < 0:
            raise SDMInputError(f"s must be a non-negative integer, got {self.s!r}")
        if int(self.zoom) != self.zoom or not 0 <= self.zoom <= self.s:
            raise SDMInputError(f"zoom must be an integer in [0, s] = [0, {self.s}], got {self.zoom!r}")
        if not (math.isfinite(self.lr_decay) and self.lr_decay > 0):
            raise SDMInputError(f"lr_decay must be a positive finite number, got {self.lr_decay!r}")
        RULES.resolve(self.flow)  # SDMInputError naming flow: not a registered name, a Rule or a flow function
        if not (math.isfinite(self.depth_lr_scale) and self.depth_lr_scale > 0):
            raise SDMInputError(f"depth_lr_scale must be a positive finite number, got {self.depth_lr_scale!r}")
        if isinstance(self.depth_zoom, bool) or int(self.depth_zoom) != self.depth_zoom or self.depth_zoom < 0:
            raise SDMInputError(f"depth_zoom must be a non-negative integer, got {self.depth_zoom!r}")

    def rate_scale(self, level: int, like: torch.Tensor) -> torch.Tensor:
        """``(3,)`` per-parameter learning-rate factors of ``(a, b, c)`` at zoom ``level`` (with ``fit_depth``).

        ``(1, 1, depth_lr_scale)``, and ``(1, 1, 0)`` below ``min(depth_zoom, s)``; dtype and device of ``like``.
        """
        depth = self.depth_lr_scale if level >= min(self.depth_zoom, self.s) else 0.0
        return torch.tensor([1.0, 1.0, depth], dtype=like.dtype, device=like.device)


@dataclass
class History:
    """What a training run did, step by step (CPU tensors, whatever device trained).

    Attributes:
        theta: ``(steps + 1, 2)`` float64 ``(a, b)`` in metres, before the first step and after each.
        loss: ``(steps,)`` float64 loss ``J`` of each step's batch (metres).
        level: ``(steps,)`` int64 zoom level of each step.
        lr: ``(steps,)`` float64 learning rate of each step.
        settings: the settings of the run.
    """

    theta: torch.Tensor
    loss: torch.Tensor
    level: torch.Tensor
    lr: torch.Tensor
    settings: TrainSettings

    @property
    def final_theta(self) -> tuple[float, ...]:
        """``(a, b)``, or ``(a, b, c)`` when the run fitted depth."""
        return tuple(self.theta[-1].tolist())

    def to_frame(self):
        """A pandas DataFrame with one row per step: ``step, level, lr, loss, a, b`` (theta after the step)."""
        import pandas as pd

        steps = len(self.loss)
        return pd.DataFrame(
            {
                "step": range(1, steps + 1),
                "level": self.level.tolist(),
                "lr": self.lr.tolist(),
                "loss": self.loss.tolist(),
                "a": self.theta[1:, 0].tolist(),
                "b": self.theta[1:, 1].tolist(),
            }
        )


def train(
    train_set: ConfigurationSet,
    settings: TrainSettings = TrainSettings(),
    camera: Camera | None = None,
    progress: bool = True,
    method: str = "fast",
    theta0: tuple[float, ...] = (0.0, 0.0),
    device: torch.device | str | None = None,
) -> History:
    """Recover the shift from a training set: :func:`train_runs` with one run (``R = 1``).

    Args:
        train_set: packed configurations (points ``Q`` and targets ``L``).
        settings: hyper-parameters.
        camera: camera and screen; default the set's own.
        progress: show a progress bar.
        method: SDM implementation, ``"fast"`` or ``"dense"``.
        theta0: starting shift ``(a, b)`` (or ``(a, b, c)`` with ``fit_depth``) in metres.
        device: where to train (``"cpu"``, ``"cuda"``, ...); default the set's device.
            The shuffling is drawn on the CPU from ``settings.seed`` whatever the
            device, so every device trains on the same mini-batches.

    Returns:
        :class:`History` (on the CPU).

    >>> from sdm import ConfigurationSet, build_configuration, distance
    >>> from sdm.data.synthetic import synthetic_images
    >>> images = synthetic_images(32)  # the default synthetic data's first 32 images: car centres, metres
    >>> data = ConfigurationSet.from_configurations([build_configuration(image.centres) for image in images])
    >>> history = train(data, TrainSettings(n_epoch=2), progress=False)
    >>> history.theta.shape  # (steps + 1, 2): 5 levels of 2 epochs of 2 batches of 16
    torch.Size([21, 2])
    >>> round(distance(history.final_theta), 2)  # metres from SKY_SHIFT
    0.02
    """
    runs = train_runs(train_set, [train_set.targets], [settings], camera, device, theta0=[theta0], method=method,
                      progress=progress)
    return History(runs.theta[:, 0].contiguous(), runs.loss[:, 0].contiguous(), runs.level, runs.lr, settings)

@dataclass
class RunsHistory:
    """What :func:`train_runs` did: the theta of every run, step by step (CPU tensors).

    Attributes:
        theta: ``(steps + 1, R, 2)`` float64 ``(a, b)`` in metres of each run, before the first step and after
            each; ``(steps + 1, R, 3)`` ``(a, b, c)`` when the runs fitted depth. With parameters attached to
            points (``param_index``), ``(epochs + 1, R, K, 2)``: every row's ``(a, b)`` before the first step and
            after each epoch (a row moves only in the steps that draw its configurations, and ``K`` rows per
            step would make the history ``K`` times the run).
        loss: ``(steps, R)`` float64 loss ``J`` of each run's mini-batch at each step (metres; 0 where the
            run's batch held no point).
        level: ``(steps,)`` int64 zoom level of each step.
        lr: ``(steps,)`` float64 learning rate of each step (the same for every run).
        settings: the settings of each run.
        theta_steps: ``(len(theta),)`` int64, the number of steps taken when each entry of ``theta`` was
            recorded (``0, 1, 2, ...`` for the shared shift).
    """

    theta: torch.Tensor
    loss: torch.Tensor
    level: torch.Tensor
    lr: torch.Tensor
    settings: list[TrainSettings]
    theta_steps: torch.Tensor | None = None

    def __post_init__(self) -> None:
        if self.theta_steps is None:
            self.theta_steps = torch.arange(self.theta.shape[0], dtype=torch.int64)

    @property
    def final_theta(self) -> list[tuple[float, ...]]:
        """``(a, b)`` (or ``(a, b, c)`` with depth) of each run after its last step."""
        return [tuple(pair) for pair in self.theta[-1].tolist()]


def train_runs(
    train_set: ConfigurationSet,
    targets: Sequence[torch.Tensor],
    settings: Sequence[TrainSettings],
    camera: Camera | None = None,
    device: torch.device | str | None = None,
    *,
    theta0: Sequence[Sequence[float]] | torch.Tensor | None = None,
    method: str = "fast",
    progress: bool = False,
    param_index: torch.Tensor | None = None,
    row_rate: torch.Tensor | None = None,
) -> RunsHistory:
    """``R`` independent training runs on the same points as one program: the one training engine.

    Run ``r`` trains on the points of ``train_set`` with its own targets ``targets[r]``,
    its own shuffling (``settings[r].seed``) and its own start ``theta0[r]``; runs never
    interact. :func:`train` is this with ``R = 1``. Two paths, the same theta histories:

    * **compiled** (CPU, float64 points, ``method="fast"``, a flow with a compiled form
      (:meth:`sdm.mapping.rules.Rule.kernel_flows`), no ``fit_depth``, the kernel of :mod:`sdm.mapping.native`
      available): Python draws every epoch's shuffling and zooms out every run's targets
      once, and one C call (``sdm_train``) does every level, epoch, mini-batch, chain,
      flow, loss and SGD step, with the torch path's float operations in its order:
      every run's theta history equals the torch path's to the bit
      (``tests/test_native.py``); only the loss is summed in another order (equal to
      1e-12 relative).
    * **torch** (everything else: CUDA, other rules, ``fit_depth``, ``"dense"``, no
      kernel): each step packs the ``R`` runs' mini-batches as ``R x batch_size``
      configurations of one layer call, run ``r``'s points moved by its own theta;
      autograd sums the flow per run. Flows are sums of signs, exact in float64 in
      any order, so each run's theta history equals the single-run loop of
      ``tests/train_reference.py`` to the bit (``test_train.py``). With ``fit_depth``
      theta is ``(R, 3)`` and each run's ``c`` is moved by its own depth flow
      (:mod:`sdm.depth`); that flow is a float sum, which packed runs may round
      differently: within 1e-12 m of the reference (``test_depth.py``), to the bit for ``R = 1``.

    **Parameters attached to points** (``param_index``; the paper's fundamental problem): theta is ``K``
    rows ``(a, b)`` per run, and point ``i`` is moved by the sum of its rows ``param_index[i]`` (one column:
    one row per point, e.g. one per configuration or one per car; two: a camera row shared by many points
    plus a residual row). A row's flow is the sum of its points' flows, and one SGD step moves every row by
    its own flow. ``param_index=None`` is the paper's case, ``K = 1`` row shared by every point (the
    shift ``(a, b)``): the same engine, whose histories are unchanged. Both paths take it (the compiled one
    moves each point by its rows' sum in the kernel); flows are exact sums, so both give every row the history
    of the plain single-run loop of ``tests/train_reference.py`` to the bit (``tests/test_param_index.py``).

    Args:
        train_set: packed configurations; their own targets are not used (pass ``train_set.targets``
            to train on them: its zoomed-out pyramid is then the set's cached one).
        targets: ``R`` tensors ``(N, H, W)`` bool, run ``r``'s training targets.
        settings: ``R`` settings; all fields but ``seed`` must agree (one learning-rate schedule,
            one ``flow``, one ``fit_depth``, ``depth_lr_scale`` and ``depth_zoom``).
        camera: camera and screen; default the set's own.
        device: where to train; default the set's device. The shuffling is drawn on the CPU.
        theta0: ``None`` (every run starts at zero) or ``R`` starts ``(a, b)`` (``(a, b, c)``, or
            ``(a, b)`` meaning ``c = 0``, with ``fit_depth``), metres; with ``param_index``, ``R`` starts
            ``(K, 2)``.
        method: SDM implementation, ``"fast"`` or ``"dense"`` (the grid reference: one run only).
        progress: show a progress bar.
        param_index: ``None`` (one shift for every point) or ``(P,)`` / ``(P, G)`` integer tensor over the
            set's ``P`` points: the rows of theta that move each point (see above; any device: it is moved to
            the set's). Every row ``0 .. K-1`` must move some point (``K = max + 1``).
        row_rate: ``None`` or ``(K,)`` positive factors, row ``k``'s step ``rate * row_rate[k] * flow_k`` (with
            ``param_index``): a row of few points gets a flow of few terms, and one rate for rows of 20 and of
            2,000 points moves the first too little or the second too far (:func:`rates_per_point`).

    Returns:
        :class:`RunsHistory` (on the CPU).

    Raises:
        SDMInputError: naming the argument, for mismatched runs, targets or starts, a set smaller than one
            batch, an unusable ``device``, a theta that became non-finite or ended beyond :data:`THETA_BOUND`
            (naming the run, the step and the setting), a start beyond it, a run whose every point is off the screen, a
            target set without an active pixel (docs/library.md, "Divergence"), or a
            ``param_index`` that is not an integer tensor of ``P`` rows, holds a negative entry, leaves a row
            with no point, or comes with ``fit_depth`` or ``method="dense"``.

    >>> import torch
    >>> from sdm import ConfigurationSet, add_target_noise, build_configuration, distance
    >>> from sdm.data.synthetic import synthetic_images
    >>> images = synthetic_images(32)  # the default synthetic data's first 32 images: car centres, metres
    >>> data = ConfigurationSet.from_configurations([build_configuration(image.centres) for image in images])
    >>> noisy = add_target_noise(data.targets, 2, torch.Generator().manual_seed(1))  # Table 2's noise, level 2
    >>> runs = train_runs(data, [data.targets, noisy], [TrainSettings(n_epoch=2, seed=0), TrainSettings(n_epoch=2, seed=1)])
    >>> runs.theta.shape  # (steps + 1, R, 2)
    torch.Size([21, 2, 2])
    >>> [round(distance(theta), 2) for theta in runs.final_theta]  # noise-free, noisy: metres from SKY_SHIFT
    [0.02, 0.03]
    """
    runs = _checked_runs(train_set, targets, settings, camera, device, theta0, method, param_index, row_rate)
    train_set, settings, common, rows, starts = runs.train_set, runs.settings, runs.common, runs.rows, runs.starts
    n_configs, batch_size = len(train_set), common.batch_size

    levels = list(range(common.s, common.zoom - 1, -1))
    rates, rate = [], common.lr
    for _ in levels:  # the learning rate of each level: lr, then lr_decay times the last
        rates.append(rate)
        rate *= common.lr_decay
    # Every epoch's shuffling of every run, (levels * n_epoch, R, N): each run's generator draws its
    # permutations in epoch order, as the run alone would.
    orders = _shufflings([one.seed for one in settings], n_configs, len(levels) * common.n_epoch)
    steps_per_level = common.n_epoch * (n_configs // batch_size)
    total = len(levels) * steps_per_level
    step_levels = torch.tensor(levels, dtype=torch.int64, device="cpu").repeat_interleave(steps_per_level)
    step_rates = torch.tensor(rates, dtype=torch.float64, device="cpu").repeat_interleave(steps_per_level)

    record_every = 1 if rows is None else n_configs // batch_size  # rows: after every epoch
    with tqdm(total=total, disable=not progress, desc="SDM training", unit="step", leave=False) as bar:
        thetas, losses = _train_program(train_set, targets, runs.own_targets, settings, runs.camera, method, levels,
                                        rates, orders, starts, bar, rows, record_every, runs.row_rate)
    theta_steps = torch.arange(0, total + 1, record_every, dtype=torch.int64, device="cpu")
    _check_divergence(thetas.cpu(), theta_steps, step_rates, runs)
    return RunsHistory(thetas.cpu(), losses.cpu(), step_levels, step_rates, settings, theta_steps)


@dataclass
class _Runs:
    """The arguments of :func:`train_runs` (and :func:`refine_runs`) after :func:`_checked_runs`."""

    train_set: ConfigurationSet  # on the training device
    settings: list[TrainSettings]
    common: TrainSettings  # settings[0]: every field but seed is every run's
    camera: Camera
    own_targets: list[bool]  # run r trains on the set's own targets
    rows: torch.Tensor | None  # the checked (P, G) param_index
    starts: torch.Tensor  # (R, 2), (R, 3) with fit_depth, (R, K, 2) with rows; float64 on the device
    row_rate: torch.Tensor | None  # (K,) float64 on the device


def _checked_runs(train_set, targets, settings, camera, device, theta0, method, param_index, row_rate) -> _Runs:
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
        train_set = train_set.to(_usable_device(device))
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
    rows = None if param_index is None else check_param_index(param_index, train_set, _theta0_rows(theta0))
    if rows is not None and (common.fit_depth or method == "dense"):
        raise SDMInputError("param_index: parameters attached to points train the shift (a, b) with method 'fast'; "
                            f"got fit_depth={common.fit_depth}, method={method!r}")
    starts = _starts(theta0, n_runs, common.fit_depth, device, n_rows=None if rows is None else int(rows.max()) + 1)
    beyond = (starts.abs().reshape(n_runs, -1) > THETA_BOUND).any(1)
    if bool(beyond.any()):
        run = int(beyond.nonzero()[0])
        raise SDMInputError(f"theta0[{run}] lies beyond the bound of {THETA_BOUND} m per component (THETA_BOUND): "
                            f"{starts[run].tolist()} is no start the flow can correct")
    for run, run_targets in enumerate(targets):
        # (a set without points trains to zero) The bytes' max: exact for bool, and ten times cheaper than any().
        if train_set.points.shape[0] and not (run_targets.numel() and bool(run_targets.view(torch.uint8).max())):
            raise SDMInputError(f"targets[{run}] holds no active pixel: the flow vanishes for every point of run {run}")
    runs = _Runs(train_set, settings, common, camera, own_targets, rows, starts, _row_rate(row_rate, rows, device))
    _check_on_screen(runs, starts.cpu(), "theta0", "its start")
    return runs


def _check_divergence(thetas: torch.Tensor, theta_steps: torch.Tensor, step_rates: torch.Tensor, runs: _Runs) -> None:
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
    _check_on_screen(runs, thetas[-1], "theta", f"step {int(theta_steps[-1])}")


def _check_on_screen(runs: _Runs, theta: torch.Tensor, name: str, when: str) -> None:
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
        lands = _any_on_screen(*probe, theta[run], runs.camera) or _any_on_screen(points, rows, theta[run],
                                                                                runs.camera)
        if not lands:
            raise SDMInputError(f"{name}: every point of run {run} is off the {height} x {width} screen at {when} "
                                f"(theta {theta[run].tolist()}): the flow vanishes; start closer or lower lr")


def _any_on_screen(points: torch.Tensor, rows: torch.Tensor | None, theta: torch.Tensor, camera: Camera) -> bool:
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


def rates_per_point(param_index: torch.Tensor) -> torch.Tensor:
    """``(K,)`` float64 row rates (``train_runs(row_rate=)``) that make a row's rate per point the same for every row:
    the mean number of points per row over each row's own (points counted once per column that names the row)."""
    rows = param_index.reshape(param_index.shape[0], -1).to(torch.int64)
    counts = torch.bincount(rows.reshape(-1)).to(torch.float64)
    return counts.mean() / counts


def _theta0_rows(theta0) -> int | None:
    """The rows ``K`` of the first start of ``theta0`` where it has that shape (``(K, 2)``), else ``None``: then the
    index's own count, and the starts are checked against it (:func:`_starts`)."""
    if theta0 is None or len(theta0) == 0:
        return None
    first = torch.as_tensor(theta0[0])
    return int(first.shape[0]) if first.dim() == 2 and first.shape[0] > 0 else None


def _row_rate(row_rate, rows, device) -> torch.Tensor | None:
    """``row_rate`` checked against the checked ``rows``: ``(K,)`` float64 on ``device``, or ``None``."""
    if row_rate is None:
        return None
    if rows is None:
        raise SDMInputError("row_rate needs param_index (it scales the rows' rates)")
    n_rows = int(rows.max()) + 1
    rate = torch.as_tensor(row_rate)
    if rate.shape != (n_rows,) or not rate.is_floating_point() or not bool((torch.isfinite(rate) & (rate > 0)).all()):
        raise SDMInputError(f"row_rate must be {n_rows} positive finite numbers (one per row of param_index), got "
                            f"{rate.dtype} {tuple(rate.shape)}")
    return rate.to(dtype=torch.float64, device=device)


@dataclass(frozen=True)
class Refinement:
    """A documented extension of the paper's schedule: SGD steps at the finest level with another rule.

    After the levels ``s .. zoom`` of :class:`TrainSettings`, ``passes`` passes of ``pass_steps`` SGD steps each
    at level ``zoom`` with the gradient rule ``flow``; pass ``i`` (from 0) runs at the rate of level
    ``zoom + rate_from`` times ``lr_decay^i`` (by default four times the last level's rate, then halving each
    pass: the paper's halving, continued per pass), with the chain ``s .. zoom`` of the last level
    (:func:`refine_runs`).

    The passes are counted in SGD steps, not in epochs, so the refinement's strength does not depend on the size
    of the training set: 4 passes of 96 steps are 12 epochs of the default's 512 configurations (batches of 16),
    and 192 epochs of a 41-configuration set (docs/method/floor.md, "The schedule that reaches the floor").

    ``closed_centred_r1`` brings theta within a few millimetres, where ``group_crossing`` (whose fixed point is
    near the floor but whose pull far from it is weak) refines it (docs/method/floor.md, "A rule aimed at the floor").

    ``group_crossing`` pulls theta only towards pixel crossings within its kernel's half-width. The passes narrow
    it: the last pass runs at ``last_width`` (the rule's own :data:`~sdm.mapping.crossing.CROSSING_WIDTH`, whose
    fixed point the schedule keeps), each earlier pass at twice the next one's, at most ``first_width``
    (:attr:`widths`; 4 passes: 16, 8, 4, 2e-3 m). On sparse real frames (few rigid groups, 0.2 m of theta per
    pixel) theta ends ``closed_centred_r1``'s levels farther than 2e-3 m from any crossing that lowers the count;
    the wide first passes, at the full rate, reach them. On dense data the same passes scatter theta by a few
    millimetres; the narrower passes pull it back, given steps enough (96 a pass: docs/method/floor.md, "The
    refinement on the real sample").

    Attributes:
        flow: a rule name, or a :class:`~sdm.mapping.rules.Rule` (:meth:`sdm.mapping.rules.RuleRegistry.resolve`).
        passes: passes, a positive integer.
        rate_from: the first pass's rate is level ``zoom + rate_from``'s (a non-negative integer; 2 was chosen
            on runs no table holds: docs/method/floor.md, "The schedule that reaches the floor").
        moves_c: with ``fit_depth``, the passes move ``c`` too (at ``depth_lr_scale`` times their rate), whatever
            ``depth_zoom`` says: ``group_crossing``'s depth flow at theta* under noise is less biased at zoom 0 than
            the paper's rule's at zoom 1 (measured by ``sdm.experiments.depth_bias``: Table 5's ``table5_bias``).
        pass_steps: SGD steps per pass, a positive integer (96: three epochs of the default's 512 configurations;
            chosen on runs no table holds: docs/method/floor.md, "The refinement on the real sample").
        first_width: ``group_crossing``'s widest kernel half-width, metres (positive, at least ``last_width``;
            16e-3 m, chosen on runs no table holds: docs/method/floor.md, "The refinement on the real sample").
        last_width: the last pass's kernel half-width, metres (positive; the rule's own, 2e-3 m).
    """

    flow: str | Rule = "group_crossing"
    passes: int = 4
    rate_from: int = 2
    moves_c: bool = True
    pass_steps: int = 96
    first_width: float = 16e-3
    last_width: float = CROSSING_WIDTH

    def __post_init__(self) -> None:
        RULES.resolve(self.flow)
        for name, least in (("passes", 1), ("rate_from", 0), ("pass_steps", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                kind = "a positive" if least else "a non-negative"
                raise SDMInputError(f"refinement {name} must be {kind} integer, got {value!r}")
        if not isinstance(self.moves_c, bool):
            raise SDMInputError(f"refinement moves_c must be True or False, got {self.moves_c!r}")
        for name in ("first_width", "last_width"):
            check_crossing_width(getattr(self, name), f"refinement {name}")
        if self.first_width < self.last_width:
            raise SDMInputError(f"refinement first_width ({self.first_width!r} m) must be at least last_width "
                                f"({self.last_width!r} m): the passes narrow the kernel")

    @property
    def steps(self) -> int:
        """The refinement's SGD steps, ``passes * pass_steps``."""
        return self.passes * self.pass_steps

    @property
    def widths(self) -> list[float]:
        """``group_crossing``'s kernel half-width of each pass, metres: ``last_width`` on the last pass, twice the
        next pass's on each earlier one, at most ``first_width``."""
        widths, width = [], float(self.last_width)
        for _ in range(self.passes):
            widths.append(width)
            width = min(2.0 * width, float(self.first_width))
        return widths[::-1]

    def rates(self, settings: TrainSettings) -> list[float]:
        """The learning rate of each pass (metres per unit of summed flow): level ``zoom + rate_from``'s rate times
        ``lr_decay^i``, whatever the pass's kernel width."""
        rate = settings.lr * settings.lr_decay ** max(settings.s - settings.zoom - self.rate_from, 0)
        return [rate * settings.lr_decay ** i for i in range(self.passes)]


def parse_schedule(name: str) -> tuple[str, Refinement | None]:
    """A training schedule by name: ``"RULE"`` (the paper's schedule, rule ``RULE``) or ``"RULE+REFINE:E"``
    (then ``E`` refinement passes of :attr:`Refinement.pass_steps` SGD steps with rule ``REFINE``,
    :class:`Refinement`; ``"RULE+REFINE"``: 4 passes). Every other choice of the passes is the class's default:
    their rates, and ``group_crossing``'s kernel half-widths narrowing to 2e-3 m on the last pass
    (:attr:`Refinement.widths`: 16, 8, 4, 2e-3 m for ``:4``).

    Table 4 (``research.rules.names``) and ``benchmarks/flow_rules.py --rules`` name schedules this way.

    Returns:
        ``(flow, refinement)``: the schedule's rule and its :class:`Refinement`, or ``None``.

    Raises:
        SDMInputError: naming ``flow`` for an unknown rule, the schedule for a malformed pass count.
    """
    if not isinstance(name, str):
        raise SDMInputError(f"a schedule is a rule name or 'RULE+REFINE:E', got {name!r}")
    flow, plus, refined = name.partition("+")
    RULES.resolve(flow)
    if not plus:
        return flow, None
    refine, colon, passes = refined.partition(":")
    if colon and not (passes.isdigit() and passes[0] != "0"):
        raise SDMInputError(f"schedule {name!r}: the passes after ':' must be a positive integer, got {passes!r}")
    return flow, Refinement(refine, int(passes) if colon else Refinement.passes)


def refine_seed(seed: int) -> int:
    """The seed of the refinement passes' shuffling of a run seeded ``seed`` (a hash, stable across platforms)."""
    return int(np.random.SeedSequence([int(seed), 20]).generate_state(1, dtype=np.uint32)[0])


def refine_runs(train_set: ConfigurationSet, targets: Sequence[torch.Tensor], settings: Sequence[TrainSettings],
                history: RunsHistory, refinement: Refinement, camera: Camera | None = None,
                device: torch.device | str | None = None, param_index: torch.Tensor | None = None,
                row_rate: torch.Tensor | None = None) -> RunsHistory:
    """``history`` (of :func:`train_runs` with these arguments) continued by ``refinement``'s passes.

    The passes train at level ``zoom`` only, through the whole chain ``s .. zoom`` (the forward of the
    schedule's last level), from each run's last theta, on the paths of :func:`train_runs` (compiled where
    it applies: for ``group_crossing`` on float64 CPU points; else packed runs in torch). Their steps are
    epochs of the training set (shuffled mini-batches, the incomplete last one dropped): run ``r`` draws one
    permutation per epoch from a generator seeded :func:`refine_seed` ``(settings[r].seed)``. A pass is the
    fewest whole epochs that hold its ``pass_steps`` steps, cut after them, at its own rate and
    ``group_crossing`` kernel half-width (:meth:`Refinement.rates`, :attr:`Refinement.widths`): where an epoch's
    steps divide ``pass_steps`` (the default's 32 steps an epoch; 2 of a 41-configuration set) no step is cut
    and every pass is one program; elsewhere each pass is its own program and the steps of its last epoch beyond ``pass_steps``
    are computed and dropped (a set of more than ``16 * pass_steps`` configurations computes a whole epoch
    per pass). Returns the whole history: the steps of ``history``, then the refinement's
    :attr:`Refinement.steps`. ``param_index``: that of :func:`train_runs` (the passes move the same rows, with
    ``row_rate``; their theta is recorded after every step).
    """
    if not isinstance(history, RunsHistory):
        raise SDMInputError(f"history must be the RunsHistory of train_runs, got {type(history).__name__}")
    trained_rows = history.theta.dim() == 4  # (steps + 1, R, K, 2): trained with param_index
    if trained_rows != (param_index is not None):
        raise SDMInputError(
            "param_index: the history was trained with parameters attached to points "
            f"({history.theta.shape[2]} rows a run); pass its param_index" if trained_rows else
            "param_index: the history was trained with one shift a run (no param_index); refine it without one")
    if history.theta.dim() < 3 or history.theta.shape[1] != len(settings):
        raise SDMInputError(f"history holds {history.theta.shape[1] if history.theta.dim() > 1 else 0} runs, "
                            f"settings {len(settings)}: refine the runs it trained")
    runs = _checked_runs(train_set, targets, settings, camera, device, history.theta[-1], "fast", param_index,
                         row_rate)
    train_set, settings, camera, rows, row_rate = runs.train_set, runs.settings, runs.camera, runs.rows, runs.row_rate
    own_targets, theta = runs.own_targets, runs.starts
    passes = [replace(one, n_epoch=1, flow=refinement.flow,
                      depth_zoom=one.zoom if refinement.moves_c else one.depth_zoom) for one in settings]
    common = passes[0]
    per_epoch = len(train_set) // common.batch_size
    epochs_per_pass = -(-refinement.pass_steps // per_epoch)
    orders = _shufflings([refine_seed(one.seed) for one in settings], len(train_set),
                         refinement.passes * epochs_per_pass)
    rates, widths = refinement.rates(common), refinement.widths
    whole = refinement.pass_steps % per_epoch == 0  # no step cut: every pass in one program
    programs = [range(refinement.passes)] if whole else [range(i, i + 1) for i in range(refinement.passes)]
    thetas, losses = [], []
    for program in programs:
        epochs = [i * epochs_per_pass + j for i in program for j in range(epochs_per_pass)]
        with tqdm(total=0, disable=True) as bar:
            steps, step_losses = _train_program(train_set, targets, own_targets, passes, camera, "fast",
                                                [common.zoom] * len(epochs), [rates[i // epochs_per_pass] for i in epochs],
                                                orders[epochs], theta, bar, rows, 1, row_rate,
                                                [widths[i // epochs_per_pass] for i in epochs])
        kept = len(program) * refinement.pass_steps  # the steps of the program's passes; the rest are cut
        thetas.append(steps[1 : kept + 1].cpu())
        losses.append(step_losses[:kept].cpu())
        theta = steps[kept]
    step_rates = torch.tensor(rates, dtype=torch.float64, device="cpu").repeat_interleave(refinement.pass_steps)
    recorded = torch.arange(1, refinement.steps + 1, dtype=torch.int64, device="cpu") + int(history.theta_steps[-1])
    _check_divergence(torch.cat(thetas), recorded, torch.cat((history.lr, step_rates)), runs)
    return RunsHistory(torch.cat((history.theta, *thetas)), torch.cat((history.loss, *losses)),
                       torch.cat((history.level, torch.full((refinement.steps,), common.zoom, dtype=torch.int64))),
                       torch.cat((history.lr, step_rates)), settings, torch.cat((history.theta_steps, recorded)))


def _shufflings(seeds: Sequence[int], n_configs: int, n_epochs: int) -> torch.Tensor:
    """``(n_epochs, R, N)`` int64 CPU: each run's generator (seeded ``seeds[r]``) draws its permutations in
    epoch order, as the run alone would."""
    generators = [torch.Generator(device="cpu").manual_seed(int(seed)) for seed in seeds]
    return torch.stack([torch.stack([torch.randperm(n_configs, generator=g, device="cpu") for g in generators])
                        for _ in range(n_epochs)])


def _run_pyramids(train_set: ConfigurationSet, targets: Sequence[torch.Tensor], own_targets: Sequence[bool],
                  steps: int) -> list[list[torch.Tensor]]:
    """Run r's zoomed-out targets, levels 0..steps, on the set's device (the set's cached pyramid for its own)."""
    return [train_set.pyramid(steps) if own else target_pyramid(run_targets.to(train_set.device), steps)
            for own, run_targets in zip(own_targets, targets)]


def _kernel_targets(train_set: ConfigurationSet, target: torch.Tensor, own: bool, steps: int,
                    levels: list[int]) -> list[torch.Tensor | None]:
    """One run's target at each loss level for the compiled trainer (:func:`sdm.mapping.native.train_program`).

    ``target`` ``(N, H, W)`` bool is the run's. The set's cached pyramid level where ``own``; else ``target``
    at level 0 and ``None`` above it, where the kernel zooms ``target`` out itself (no torch pyramid is made).
    A rule's prepared target (``closed_centred_r1``'s closing) is the kernel's own work.
    """
    pyramid = train_set.pyramid(steps) if own else None
    return [pyramid[level] if pyramid is not None else (target if level == 0 else None) for level in levels]


def _usable_device(device: torch.device | str) -> torch.device:
    """``device`` as a :class:`torch.device`; :class:`SDMInputError` naming it where this torch cannot use it."""
    try:
        device = torch.device(device)
        torch.empty(0, device=device)  # e.g. "cuda" on a CPU-only torch: an AssertionError inside torch
    except (AssertionError, RuntimeError, TypeError, ValueError) as error:
        raise SDMInputError(f"device {str(device)!r} is not available to this torch: {error}") from None
    return device


def _starts(theta0, n_runs: int, fit_depth: bool, device: torch.device, n_rows: int | None = None) -> torch.Tensor:
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


def _train_program(train_set, targets, own_targets, settings, camera, method, levels, rates, orders, starts, bar,
                   rows=None, record_every=1, row_rate=None, widths=None):
    """The steps of :func:`train_runs` at ``levels`` (``settings[0].n_epoch`` epochs each, rates ``rates``,
    shufflings ``orders``) from ``starts``, on the compiled path where it applies, else the torch path:
    ``(thetas (steps / record_every + 1, R, ...), losses (steps, R))`` on the set's device. ``rows``: ``None``
    or the checked ``(P, G)`` param_index (:func:`check_param_index`), ``row_rate`` ``None`` or its rows' rates;
    ``widths``: ``None`` or, per entry of ``levels``, ``group_crossing``'s kernel half-width there (metres;
    :attr:`Refinement.widths`)."""
    common = settings[0]
    device = train_set.device
    rule = RULES.resolve(common.flow)
    windows = rule.kernel_flows(levels)  # None: no compiled form
    if not (method == "fast" and not common.fit_depth and windows is not None and device.type == "cpu"
            and train_set.points.dtype == torch.float64 and native.enabled()
            and native.trains_screen(camera.screen_shape)):
        # the compiled groups split by rows; the torch rule cannot
        if rows is not None and windows is not None and KernelFlow.CROSSING in windows:
            _check_rigid_rows(train_set, rows)
        pyramids = _run_pyramids(train_set, targets, own_targets, common.s)  # run r's levels 0..s
        return _train_torch(train_set, pyramids, settings, camera, method, levels, rates, orders, starts, bar,
                            rows, record_every, row_rate, widths)
    bases = [run_targets.to(device) for run_targets in targets]
    run_levels = [_kernel_targets(train_set, base, own, common.s, levels)
                  for base, own in zip(bases, own_targets)]
    thetas, losses, failed = native.train_program(
        train_set.points, train_set.pixels, train_set.rank, train_set.offsets, camera, common.s, levels,
        common.n_epoch, common.batch_size, rates, windows, orders, run_levels, starts, bases, rows, record_every,
        row_rate, widths)
    if bool((failed >= 0).any()):
        step = int(failed[failed >= 0].min())
        run = int((failed == step).nonzero()[0])
        rate = rates[step // (common.n_epoch * (len(train_set) // common.batch_size))]
        raise SDMInputError(f"theta of run {run} became non-finite at step {step + 1} (lr {rate!r} too large?)")
    bar.update(losses.shape[0])
    return thetas, losses


def _check_rigid_rows(train_set: ConfigurationSet, rows: torch.Tensor) -> None:
    """:class:`SDMInputError` naming ``param_index`` where a rigid group of ``group_crossing`` (the points of one
    configuration at one depth, :func:`sdm.mapping.crossing.rigid_groups`) holds points of different rows, on the
    torch path: its rule moves each group as one, which then would not be one shift. (The compiled trainer splits
    such groups by rows.)"""
    from .mapping.crossing import rigid_groups

    if rows.shape[0] == 0:
        return
    config = torch.repeat_interleave(torch.arange(len(train_set), device=train_set.device), train_set.counts)
    group, first = rigid_groups(train_set.points[:, :2], train_set.points[:, 2], config)
    differs = (rows != rows.index_select(0, first.index_select(0, group))).any(1)
    if bool(differs.any()):
        point = int(differs.nonzero()[0])
        raise SDMInputError(f"param_index: group_crossing moves the points of one configuration at one depth as "
                            f"one, but point {point} of configuration {int(config[point])} has rows "
                            f"{rows[point].tolist()} and another point at its depth has others")


def _train_torch(train_set, pyramids, settings, camera, method, levels, rates, orders, starts, bar, rows=None,
                 record_every=1, row_rate=None, widths=None):
    """The torch path of :func:`train_runs`: ``(thetas (steps / record_every + 1, R, ...), losses (steps, R))`` on
    the set's device."""
    common, n_runs = settings[0], len(settings)
    device, batch_size = train_set.device, common.batch_size
    # Run r's target of configuration c is row r * N + c of each level.
    pyramid = pyramids[0] if n_runs == 1 else [torch.cat(level) for level in zip(*pyramids)]
    # Per entry of levels: its rule (group_crossing's kernel width may differ pass by pass) and its layer.
    # With several runs the rule is applied run by run (the chain stays one call), so each run's loss is its own.
    built, layers, runners = {}, [], []
    for index, level in enumerate(levels):
        width = None if widths is None else widths[index]
        if (level, width) not in built:
            rule = crossing_width_rule(common.flow, width)
            runner = rule if n_runs == 1 else _RunByRun(rule, n_runs, batch_size)
            built[level, width] = (SpatialDomainMapping(camera, s=common.s, zoom=level, method=method, flow=runner,
                                                        fit_depth=common.fit_depth), runner)
        layers.append(built[level, width][0])
        runners.append(built[level, width][1])
    theta = starts.clone().requires_grad_(True)
    total = len(levels) * common.n_epoch * (len(train_set) // batch_size)
    thetas = torch.empty(total // record_every + 1, *theta.shape, dtype=torch.float64, device=device)
    thetas[0] = theta.detach()
    losses = torch.zeros(total, n_runs, dtype=torch.float64, device=device)
    step = 0
    for index_level, (level, rate) in enumerate(zip(levels, rates)):
        # Per-parameter learning-rate factors: c learns at its own rate (depth_lr_scale) down to depth_zoom.
        rate_scale = common.rate_scale(level, theta) if common.fit_depth else None
        for epoch_index in range(common.n_epoch):
            epoch = _RunsEpochLayout(train_set, orders[index_level * common.n_epoch + epoch_index].to(device),
                                     batch_size, rows)
            for index in range(epoch.steps):
                batch, target_rows, run_of_point, run_bounds = epoch.batch(index)
                if batch.points.shape[0]:  # a step where every run drew empty configurations pulls nothing
                    if rows is not None:  # each point moved by the sum of its rows of its run's theta
                        moves = shift_vector(point_shifts(theta, epoch.rows_of(index), run_of_point), batch.points)
                    # One run: theta broadcast, so that autograd sums the flow as the single-run loop did.
                    elif n_runs == 1:
                        moves = shift_vector(theta[0], batch.points)
                    else:
                        moves = shift_vector(theta, batch.points).index_select(0, run_of_point)  # (P, 3)
                    rule = runners[index_level]
                    if n_runs > 1:
                        rule.bounds = run_bounds
                    out = layers[index_level](
                        batch.points + moves, batch.pixels, pyramid[level].index_select(0, target_rows),
                        batch.config, batch.rank, target_is_zoomed=True, validate=False,
                    )
                    out.loss.backward()
                    with torch.no_grad():  # plain SGD, per run: theta_r <- theta_r - lr * grad_r
                        if row_rate is not None:  # each row at its own rate (as the kernel rounds it)
                            theta -= (rate * row_rate)[:, None] * theta.grad
                        elif common.fit_depth:
                            theta -= rate * rate_scale * theta.grad
                        else:
                            theta -= rate * theta.grad
                    theta.grad = None
                    losses[step] = out.loss.detach() if n_runs == 1 else rule.losses
                    finite = torch.isfinite(theta).reshape(n_runs, -1).all(1)
                    if not bool(finite.all()):
                        run = int((~finite).nonzero()[0])
                        raise SDMInputError(f"theta of run {run} became non-finite at step {step + 1} "
                                            f"(lr {rate!r} too large?)")
                step += 1
                if step % record_every == 0:
                    thetas[step // record_every] = theta.detach()
                bar.update()
    return thetas, losses


class _RunByRun:
    """A gradient rule applied to each run's points of a packed step on their own: per-run losses.

    The rule sees exactly what a single run's step would give it (its configurations numbered
    ``0..B-1``, its ``B`` targets), so flow and loss are that run's to the bit. Set ``bounds``
    (``R + 1`` point offsets of the runs in the step) before each call; ``losses`` ``(R,)``
    holds the runs' losses after it.
    """

    def __init__(self, rule, n_runs: int, batch_size: int) -> None:
        self.rule, self.n_runs, self.batch_size = rule, n_runs, batch_size
        self.bounds: list[int] = []
        self.losses: torch.Tensor | None = None

    def __call__(self, screen, depth, config, landed, block, landing, target, zoom, camera):
        flows, losses, matched = [], [], []
        for run in range(self.n_runs):
            lo, hi = self.bounds[run], self.bounds[run + 1]
            if hi == lo:  # this run drew only empty configurations: it is not pulled
                losses.append(screen.new_zeros(()))
                continue
            first = run * self.batch_size
            flow, loss, hit = self.rule(screen[lo:hi], depth[lo:hi], config[lo:hi] - first, landed[lo:hi],
                                        block[lo:hi], landing[lo:hi], target[first : first + self.batch_size], zoom,
                                        camera)
            flows.append(flow), losses.append(loss), matched.append(hit)
        self.losses = torch.stack(losses).detach()
        return torch.cat(flows), self.losses.sum(), torch.cat(matched)


class _RunsEpochLayout:
    """One epoch of ``R`` runs: step ``i`` is the concatenation of every run's mini-batch ``i``.

    Points are gathered once per epoch in (step, run, configuration) order, so
    each step is a contiguous slice, and so is each run's part of it. In a step,
    configuration ``j`` of run ``r`` is batch configuration ``r * batch_size + j``.
    """

    def __init__(self, data: ConfigurationSet, orders: torch.Tensor, batch_size: int,
                 param_rows: torch.Tensor | None = None) -> None:
        n_runs, n_configs = orders.shape
        self.batch_size, self.n_runs = batch_size, n_runs
        self.steps = steps = n_configs // batch_size
        kept = orders[:, : steps * batch_size].reshape(n_runs, steps, batch_size)
        self.configs = kept.transpose(0, 1).reshape(-1)  # (steps * R * B,) step-major
        runs = torch.arange(n_runs, device=orders.device)[None, :, None].expand(steps, n_runs, batch_size).reshape(-1)
        self.target_rows = runs * n_configs + self.configs
        rows, position = data.rows(self.configs)  # position: each row's index into self.configs
        self.points = data.points.index_select(0, rows)
        self.pixels = data.pixels.index_select(0, rows)
        self.rank = data.rank.index_select(0, rows)
        self.param_rows = None if param_rows is None else param_rows.index_select(0, rows)  # (P_epoch, G)
        per_run = data.counts.index_select(0, self.configs).view(steps, n_runs, batch_size).sum(2)  # (steps, R)
        self.local = position % (n_runs * batch_size)
        self.run = torch.div(self.local, batch_size, rounding_mode="floor")
        self.bounds = [0] + per_run.sum(1).cumsum(0).tolist()
        self.run_bounds = torch.nn.functional.pad(per_run.cumsum(1), (1, 0)).tolist()  # (steps, R + 1) in a step

    def batch(self, index: int) -> tuple[PointBatch, torch.Tensor, torch.Tensor, list[int]]:
        """Step ``index``: its points, the target row of each of its ``R * B`` configurations, the run of each
        point, and the ``R + 1`` offsets of the runs' points in the step."""
        lo, hi = self.bounds[index], self.bounds[index + 1]
        group = self.n_runs * self.batch_size
        target_rows = self.target_rows[index * group : (index + 1) * group]
        rows = slice(lo, hi)
        batch = PointBatch(self.points[rows], self.pixels[rows], self.local[rows], self.rank[rows], None)
        return batch, target_rows, self.run[rows], self.run_bounds[index]

    def rows_of(self, index: int) -> torch.Tensor:
        """``(P_step, G)`` int64: the param_index rows of step ``index``'s points."""
        return self.param_rows[self.bounds[index] : self.bounds[index + 1]]

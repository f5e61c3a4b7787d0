"""Training: SGD on the shift theta = (a, b) through the SDM layer (paper, section 6; docs/method.md, Training and evaluation).

theta starts at (0, 0). For zoom level ``s, s-1, ..., zoom``: ``n_epoch`` passes
over the training set in shuffled mini-batches of 16 configurations (the
incomplete last batch is dropped), the loss taken at that level; the learning
rate halves after each level. The loss is the *sum* over all points of the
batch, which is what the paper's learning rates assume.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import torch
from tqdm.std import tqdm  # plain text: renders in notebooks without ipywidgets, no IProgress warning

from .batch import ConfigurationSet, PointBatch
from .camera import Camera
from .errors import SDMInputError
from .mapping import SpatialDomainMapping
from .mapping.rules import rule_by_name
from .sky import shift_vector
from .zoom import target_pyramid


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
        flow: the gradient rule, a name of :data:`sdm.FLOW_RULES` (default ``"paper"``, eq. 19).
        fit_depth: train the general shift ``(a, b, c)`` with the depth flow of :mod:`sdm.depth`
            (beyond the paper); theta, its history and ``final_theta`` then have three entries.
        depth_lr_scale: the learning rate of ``c`` relative to ``lr`` (with ``fit_depth``); 20 by a
            measured sweep (1: c lags, 10-30: within 1e-2 m, 100: diverges; docs/method.md).
        depth_zoom: the finest zoom level at which ``c`` moves (with ``fit_depth``; at least the coarsest
            level ``s``): the finer levels train ``(a, b)`` with ``c`` held. Default 1: at full resolution
            the pull on ``c`` with ``depth_lr_scale`` 20 walks along the near-degenerate direction of
            ``(b, c)`` (every point lies below the principal point) and leaves ``b`` off by about 2e-3 m
            at c = -1 m (measured; docs/method.md, "Beyond the paper").
    """

    lr: float = 3e-4
    n_epoch: int = 1
    batch_size: int = 16
    s: int = 4
    zoom: int = 0
    lr_decay: float = 0.5
    seed: int = 0
    flow: str = "paper"
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
        rule_by_name(self.flow)  # SDMInputError naming flow: a name of sdm.FLOW_RULES or of RESEARCH_RULES
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
    """Recover the shift from a training set.

    Args:
        train_set: packed configurations (points ``Q`` and targets ``L``).
        settings: hyper-parameters.
        camera: camera and screen; default the set's own.
        progress: show a progress bar.
        method: SDM implementation, ``"fast"`` or ``"dense"``.
        theta0: starting shift ``(a, b)`` in metres.
        device: where to train (``"cpu"``, ``"cuda"``, ...); default the set's device.
            The shuffling is drawn on the CPU from ``settings.seed`` whatever the
            device, so every device trains on the same mini-batches.

    Returns:
        :class:`History` (on the CPU).
    """
    camera = camera or train_set.camera
    if device is not None:
        train_set = train_set.to(device)
    device = train_set.device
    # Built first: the layer checks that the screen is divisible by 2^s before anything is zoomed out.
    layers = {level: SpatialDomainMapping(camera, s=settings.s, zoom=level, method=method, flow=settings.flow,
                                        fit_depth=settings.fit_depth)
              for level in range(settings.s, settings.zoom - 1, -1)}
    n_configs = len(train_set)
    if n_configs < settings.batch_size:
        raise SDMInputError(
            f"the training set has {n_configs} configurations, fewer than one batch of {settings.batch_size}"
        )
    start = torch.as_tensor(theta0, dtype=torch.float64, device=device)
    if settings.fit_depth and start.shape == (2,):  # (a, b) -> (a, b, 0)
        start = torch.nn.functional.pad(start, (0, 1))
    n_params = 3 if settings.fit_depth else 2
    if start.shape != (n_params,) or not bool(torch.isfinite(start).all()):
        raise SDMInputError(f"theta0 must be {n_params} finite numbers, got {theta0!r}")

    # Packed data was checked when the set was built; only theta changes, and it is checked every step.
    theta = start.clone().requires_grad_(True)
    generator = torch.Generator(device="cpu").manual_seed(settings.seed)
    pyramid = train_set.pyramid(settings.s)
    levels = range(settings.s, settings.zoom - 1, -1)
    batch_size = settings.batch_size
    batches_per_epoch = n_configs // batch_size
    total = len(levels) * settings.n_epoch * batches_per_epoch

    thetas = torch.empty(total + 1, n_params, dtype=torch.float64, device=device)
    thetas[0] = theta.detach()
    losses = torch.zeros(total, dtype=torch.float64, device=device)
    step_levels = torch.empty(total, dtype=torch.int64)
    rates = torch.empty(total, dtype=torch.float64)
    step, rate = 0, settings.lr
    with tqdm(total=total, disable=not progress, desc="SDM training", unit="step", leave=False) as bar:
        for level in levels:
            layer = layers[level]
            # Per-parameter learning-rate factors: c learns at its own rate (depth_lr_scale) down to depth_zoom.
            rate_scale = settings.rate_scale(level, start) if settings.fit_depth else None
            for _ in range(settings.n_epoch):
                order = torch.randperm(n_configs, generator=generator, device="cpu").to(device)
                epoch = _EpochLayout(train_set, order, batch_size)
                for index in range(batches_per_epoch):
                    batch, configs = epoch.batch(index)
                    if batch.points.shape[0]:  # a batch of empty configurations pulls nothing
                        out = layer(
                            batch.points + shift_vector(theta, batch.points), batch.pixels, pyramid[level].index_select(0, configs),
                            batch.config, batch.rank, target_is_zoomed=True, validate=False,
                        )
                        out.loss.backward()
                        with torch.no_grad():  # plain SGD: theta <- theta - lr * grad
                            theta -= rate * theta.grad if not settings.fit_depth else rate * rate_scale * theta.grad
                        theta.grad = None
                        losses[step] = out.loss.detach()
                        if not bool(torch.isfinite(theta).all()):
                            raise SDMInputError(f"theta became non-finite at step {step + 1} (lr {rate!r} too large?)")
                    thetas[step + 1] = theta.detach()
                    step_levels[step], rates[step] = level, rate
                    step += 1
                    bar.update()
                bar.set_postfix(level=level, a=f"{theta[0].item():.4f}", b=f"{theta[1].item():.4f}")
            rate *= settings.lr_decay
    return History(thetas.cpu(), losses.cpu(), step_levels, rates, settings)


@dataclass
class RunsHistory:
    """What :func:`train_runs` did: the theta of every run, step by step (CPU tensors).

    Attributes:
        theta: ``(steps + 1, R, 2)`` float64 ``(a, b)`` in metres of each run, before the first step and after
            each; ``(steps + 1, R, 3)`` ``(a, b, c)`` when the runs fitted depth.
        loss: ``(steps,)`` float64 loss ``J`` of each step, summed over the runs (metres).
        level: ``(steps,)`` int64 zoom level of each step.
        lr: ``(steps,)`` float64 learning rate of each step (the same for every run).
        settings: the settings of each run.
    """

    theta: torch.Tensor
    loss: torch.Tensor
    level: torch.Tensor
    lr: torch.Tensor
    settings: list[TrainSettings]

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
) -> RunsHistory:
    """``R`` independent training runs on the same points as one program: one layer call per step.

    Run ``r`` trains on the points of ``train_set`` with its own targets ``targets[r]``
    and its own shuffling (``settings[r].seed``), exactly as :func:`train` would
    alone: each step packs the ``R`` runs' mini-batches as ``R x batch_size``
    configurations of one batch (configurations never interact in the layer), the
    points of run ``r`` are moved by its own theta, and the flow reaching theta
    ``(R, 2)`` is summed per run by autograd. Flows are sums of signs, exact in
    float64 in any order, so every run's theta history equals :func:`train`'s to
    the bit (``test_train.py`` holds it). With ``fit_depth`` theta is ``(R, 3)`` and
    each run's ``c`` is moved by its own depth flow (:mod:`sdm.depth`), as
    :func:`train` moves it for one run; the depth flow is not a sum of integers, so
    the sums over a run's points may round differently than alone: every run's
    history equals :func:`train`'s to 1e-12 m (``test_depth.py`` holds it).

    Args:
        train_set: packed configurations; their own targets are not used.
        targets: ``R`` tensors ``(N, H, W)`` bool, run ``r``'s training targets.
        settings: ``R`` settings; all fields but ``seed`` must agree (one learning-rate schedule,
            one ``flow``, one ``fit_depth``, ``depth_lr_scale`` and ``depth_zoom``).
        camera: camera and screen; default the set's own.
        device: where to train; default the set's device.

    Returns:
        :class:`RunsHistory` (on the CPU).
    """
    settings = list(settings)
    n_runs = len(settings)
    if n_runs == 0 or len(targets) != n_runs:
        raise SDMInputError(f"train_runs needs one target set per run: {len(targets)} target sets, {n_runs} settings")
    shared = {replace(one, seed=0) for one in settings}
    if len(shared) != 1:
        raise SDMInputError(f"the runs' settings may differ only in seed, got {sorted(map(str, shared))}")
    common = settings[0]
    camera = camera or train_set.camera
    if device is not None:
        train_set = train_set.to(device)
    device = train_set.device
    layers = {level: SpatialDomainMapping(camera, s=common.s, zoom=level, flow=common.flow, fit_depth=common.fit_depth)
              for level in range(common.s, common.zoom - 1, -1)}
    n_configs, batch_size = len(train_set), common.batch_size
    if n_configs < batch_size:
        raise SDMInputError(f"the training set has {n_configs} configurations, fewer than one batch of {batch_size}")
    for run, run_targets in enumerate(targets):
        if tuple(run_targets.shape) != tuple(train_set.targets.shape) or run_targets.dtype != torch.bool:
            raise SDMInputError(f"targets[{run}] must be bool of shape {tuple(train_set.targets.shape)}, "
                                f"got {run_targets.dtype} {tuple(run_targets.shape)}")
    # Run r's target of configuration c is row r * N + c of each level.
    pyramid = [torch.cat(level) for level in zip(*(target_pyramid(t.to(device), common.s) for t in targets))]

    n_params = 3 if common.fit_depth else 2
    theta = torch.zeros(n_runs, n_params, dtype=torch.float64, device=device, requires_grad=True)
    generators = [torch.Generator(device="cpu").manual_seed(one.seed) for one in settings]
    levels = range(common.s, common.zoom - 1, -1)
    batches_per_epoch = n_configs // batch_size
    total = len(levels) * common.n_epoch * batches_per_epoch
    thetas = torch.empty(total + 1, n_runs, n_params, dtype=torch.float64, device=device)
    thetas[0] = theta.detach()
    losses = torch.zeros(total, dtype=torch.float64, device=device)
    step_levels = torch.empty(total, dtype=torch.int64)
    rates = torch.empty(total, dtype=torch.float64)
    step, rate = 0, common.lr
    for level in levels:
        # Per-parameter learning-rate factors, as in train().
        rate_scale = common.rate_scale(level, theta) if common.fit_depth else None
        for _ in range(common.n_epoch):
            # The same draws, in the same order, as each run's own train().
            orders = torch.stack([torch.randperm(n_configs, generator=g, device="cpu") for g in generators]).to(device)
            epoch = _RunsEpochLayout(train_set, orders, batch_size)
            for index in range(batches_per_epoch):
                batch, target_rows, run_of_point = epoch.batch(index)
                if batch.points.shape[0]:  # a step where every run drew empty configurations pulls nothing
                    moves = shift_vector(theta, batch.points).index_select(0, run_of_point)  # (P, 3)
                    out = layers[level](
                        batch.points + moves, batch.pixels, pyramid[level].index_select(0, target_rows),
                        batch.config, batch.rank, target_is_zoomed=True, validate=False,
                    )
                    out.loss.backward()
                    with torch.no_grad():  # plain SGD, per run: theta_r <- theta_r - lr * grad_r
                        theta -= rate * theta.grad if not common.fit_depth else rate * rate_scale * theta.grad
                    theta.grad = None
                    losses[step] = out.loss.detach()
                    finite = torch.isfinite(theta).all(1)
                    if not bool(finite.all()):
                        run = int((~finite).nonzero()[0])
                        raise SDMInputError(f"theta of run {run} became non-finite at step {step + 1} "
                                            f"(lr {rate!r} too large?)")
                thetas[step + 1] = theta.detach()
                step_levels[step], rates[step] = level, rate
                step += 1
        rate *= common.lr_decay
    return RunsHistory(thetas.cpu(), losses.cpu(), step_levels, rates, settings)


class _RunsEpochLayout:
    """One epoch of ``R`` runs: step ``i`` is the concatenation of every run's mini-batch ``i``.

    Points are gathered once per epoch in (step, run, configuration) order, so
    each step is a contiguous slice. In a step, configuration ``j`` of run ``r``
    is batch configuration ``r * batch_size + j``.
    """

    def __init__(self, data: ConfigurationSet, orders: torch.Tensor, batch_size: int) -> None:
        n_runs, n_configs = orders.shape
        self.batch_size, self.n_runs = batch_size, n_runs
        steps = n_configs // batch_size
        kept = orders[:, : steps * batch_size].reshape(n_runs, steps, batch_size)
        self.configs = kept.transpose(0, 1).reshape(-1)  # (steps * R * B,) step-major
        runs = torch.arange(n_runs, device=orders.device)[None, :, None].expand(steps, n_runs, batch_size).reshape(-1)
        self.target_rows = runs * n_configs + self.configs
        rows, position = data.rows(self.configs)  # position: each row's index into self.configs
        self.points = data.points.index_select(0, rows)
        self.pixels = data.pixels.index_select(0, rows)
        self.rank = data.rank.index_select(0, rows)
        counts = data.counts.index_select(0, self.configs)
        self.local = position % (n_runs * batch_size)
        self.run = torch.div(self.local, batch_size, rounding_mode="floor")
        self.bounds = [0] + counts.view(steps, -1).sum(1).cumsum(0).tolist()

    def batch(self, index: int) -> tuple[PointBatch, torch.Tensor, torch.Tensor]:
        """Step ``index``: its points, the target row of each of its ``R * B`` configurations, the run of each point."""
        lo, hi = self.bounds[index], self.bounds[index + 1]
        group = self.n_runs * self.batch_size
        target_rows = self.target_rows[index * group : (index + 1) * group]
        rows = slice(lo, hi)
        batch = PointBatch(self.points[rows], self.pixels[rows], self.local[rows], self.rank[rows], None)
        return batch, target_rows, self.run[rows]


class _EpochLayout:
    """One epoch's shuffled configurations, their points laid out batch after batch (on ``order``'s device).

    Gathering every point of the epoch once makes each mini-batch a
    contiguous slice (a view), instead of a gather per step.
    """

    def __init__(self, data: ConfigurationSet, order: torch.Tensor, batch_size: int) -> None:
        self.batch_size = batch_size
        self.configs = order[: (len(order) // batch_size) * batch_size]
        rows, _ = data.rows(self.configs)
        self.points = data.points.index_select(0, rows)
        self.pixels = data.pixels.index_select(0, rows)
        self.rank = data.rank.index_select(0, rows)
        counts = data.counts.index_select(0, self.configs)
        self.local = torch.repeat_interleave(torch.arange(len(self.configs), device=order.device) % batch_size, counts)
        per_batch = counts.view(-1, batch_size).sum(1)
        self.bounds = [0] + per_batch.cumsum(0).tolist()

    def batch(self, index: int) -> tuple[PointBatch, torch.Tensor]:
        """Batch ``index``: its points (targets left empty) and the indices of its configurations."""
        lo, hi = self.bounds[index], self.bounds[index + 1]
        configs = self.configs[index * self.batch_size : (index + 1) * self.batch_size]
        rows = slice(lo, hi)
        return PointBatch(self.points[rows], self.pixels[rows], self.local[rows], self.rank[rows], None), configs

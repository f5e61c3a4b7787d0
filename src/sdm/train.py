"""Training: SGD on the shift theta = (a, b) through the SDM layer (paper, section 6; notes, section 6).

theta starts at (0, 0). For zoom level ``s, s-1, ..., zoom``: ``n_epoch`` passes
over the training set in shuffled mini-batches of 16 configurations (the
incomplete last batch is dropped), the loss taken at that level; the learning
rate halves after each level. The loss is the *sum* over all points of the
batch, which is what the paper's learning rates assume.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from tqdm.auto import tqdm

from .batch import ConfigurationSet, PointBatch
from .camera import Camera
from .errors import SDMInputError
from .mapping import SpatialDomainMapping
from .sky import shift_vector


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
    """

    lr: float = 3e-4
    n_epoch: int = 1
    batch_size: int = 16
    s: int = 4
    zoom: int = 0
    lr_decay: float = 0.5
    seed: int = 0

    def __post_init__(self) -> None:
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
    def final_theta(self) -> tuple[float, float]:
        a, b = self.theta[-1].tolist()
        return a, b

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
    theta0: tuple[float, float] = (0.0, 0.0),
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
    layers = {level: SpatialDomainMapping(camera, s=settings.s, zoom=level, method=method)
              for level in range(settings.s, settings.zoom - 1, -1)}
    n_configs = len(train_set)
    if n_configs < settings.batch_size:
        raise SDMInputError(
            f"the training set has {n_configs} configurations, fewer than one batch of {settings.batch_size}"
        )
    start = torch.as_tensor(theta0, dtype=torch.float64, device=device)
    if start.shape != (2,) or not bool(torch.isfinite(start).all()):
        raise SDMInputError(f"theta0 must be two finite numbers (a, b), got {theta0!r}")

    # Packed data was checked when the set was built; only theta changes, and it is checked every step.
    theta = start.clone().requires_grad_(True)
    generator = torch.Generator(device="cpu").manual_seed(settings.seed)
    pyramid = train_set.pyramid(settings.s)
    levels = range(settings.s, settings.zoom - 1, -1)
    batch_size = settings.batch_size
    batches_per_epoch = n_configs // batch_size
    total = len(levels) * settings.n_epoch * batches_per_epoch

    thetas = torch.empty(total + 1, 2, dtype=torch.float64, device=device)
    thetas[0] = theta.detach()
    losses = torch.zeros(total, dtype=torch.float64, device=device)
    step_levels = torch.empty(total, dtype=torch.int64)
    rates = torch.empty(total, dtype=torch.float64)
    step, rate = 0, settings.lr
    with tqdm(total=total, disable=not progress, desc="SDM training", unit="step", leave=False) as bar:
        for level in levels:
            layer = layers[level]
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
                            theta -= rate * theta.grad
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

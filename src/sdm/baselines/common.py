"""What the baselines share: padded per-configuration tensors, projection of the shifted points,
mini-batches, settings checks and a staged Adam loop.

Every baseline sees exactly what SDM sees: the points ``Q`` of each configuration and its binary
target ``L`` (possibly noisy), and estimates ``theta = (a, b)`` in metres. The points of a
configuration at ``theta`` are ``P(Q + (a, b, 0))`` in screen pixels ``(row, col)``
(:meth:`sdm.Camera.project`); a point whose projection leaves the ``H x W`` screen has no
counterpart in the target (the target was built by dropping such points), so the point-set losses
ignore it at the current ``theta``.

Tensors live on the device of the training set's tensors; nothing is created on a fixed device.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import torch

from ..batch import ConfigurationSet
from ..camera import Camera
from ..errors import SDMInputError
from ..sky import shift_vector


@dataclass(frozen=True)
class PaddedSet:
    """A :class:`~sdm.ConfigurationSet` as zero-padded per-configuration tensors.

    Attributes:
        points: ``(N, P, 3)`` float64 points ``Q`` in metres; padding rows are ``(0, 0, 1)`` (a
            point in front of the camera, so projecting it is finite) and masked out.
        point_mask: ``(N, P)`` bool, True for real points.
        centres: ``(N, T, 2)`` float64 centres ``(row + 0.5, col + 0.5)`` of the target's active
            pixels, screen pixels; padding rows are 0 and masked out.
        centre_mask: ``(N, T)`` bool, True for real target pixels.
        screen_shape: ``(H, W)``.
    """

    points: torch.Tensor
    point_mask: torch.Tensor
    centres: torch.Tensor
    centre_mask: torch.Tensor
    screen_shape: tuple[int, int]

    def __len__(self) -> int:
        return int(self.points.shape[0])


def pad_set(data: ConfigurationSet) -> PaddedSet:
    """Pack ``data``'s points and target pixels per configuration (see :class:`PaddedSet`)."""
    n_configs = len(data)
    height, width = data.camera.screen_shape
    device = data.points.device
    counts = data.counts
    config = torch.repeat_interleave(torch.arange(n_configs, device=device), counts)
    slot = torch.arange(config.numel(), device=device) - data.offsets[:-1].index_select(0, config)
    width_points = max(int(counts.max()) if n_configs else 0, 1)
    points = torch.zeros(n_configs, width_points, 3, dtype=data.points.dtype, device=device)
    points[..., 2] = 1.0
    points[config, slot] = data.points
    point_mask = torch.zeros(n_configs, width_points, dtype=torch.bool, device=device)
    point_mask[config, slot] = True

    active = data.targets.nonzero()  # (K, 3): config, row, col, in config order
    target_counts = torch.bincount(active[:, 0], minlength=n_configs)
    target_offsets = torch.cumsum(target_counts, 0) - target_counts
    target_slot = torch.arange(active.shape[0], device=device) - target_offsets.index_select(0, active[:, 0])
    width_target = max(int(target_counts.max()) if active.numel() else 0, 1)
    centres = torch.zeros(n_configs, width_target, 2, dtype=data.points.dtype, device=device)
    centres[active[:, 0], target_slot] = active[:, 1:].to(data.points.dtype) + 0.5
    centre_mask = torch.zeros(n_configs, width_target, dtype=torch.bool, device=device)
    centre_mask[active[:, 0], target_slot] = True
    return PaddedSet(points, point_mask, centres, centre_mask, (height, width))


def project_shifted(points: torch.Tensor, theta: torch.Tensor, camera: Camera) -> torch.Tensor:
    """Screen coordinates of ``points + (a, b, 0)``.

    Args:
        points: ``(..., 3)`` float64 metres, ``z > 0`` (checked when the set was built).
        theta: ``(2,)`` shift ``(a, b)`` in metres, same dtype; may require grad.

    Returns:
        ``(..., 2)`` ``(row, col)`` in screen pixels, differentiable in ``theta``.
    """
    return camera.project(points + shift_vector(theta, points), validate=False)


def on_screen(screen: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """``(...)`` bool: continuous ``(..., 2)`` screen coordinates whose pixel is on the ``H x W`` screen."""
    height, width = shape
    row, col = screen.detach().unbind(-1)
    return (row >= 0) & (row < height) & (col >= 0) & (col < width)


def subsample(mask: torch.Tensor, k: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """Pick up to ``k`` random real entries per row of a ``(B, P)`` mask, without replacement.

    Returns:
        ``(index, kept)``: ``(B, min(k, P))`` int64 column indices and bool, False where a row
        has fewer than ``k`` real entries (those indices point at padding).
    """
    if k <= 0 or k >= mask.shape[1]:
        index = torch.arange(mask.shape[1], device=mask.device).expand(mask.shape[0], -1)
        return index, mask
    keys = torch.rand(mask.shape, generator=generator, dtype=torch.float64).to(mask.device)
    keys = torch.where(mask, keys, torch.full_like(keys, -1.0))
    top, index = torch.topk(keys, k, dim=1)
    return index, top >= 0


def batch_orders(n_configs: int, batch_size: int, generator: torch.Generator):
    """An endless stream of mini-batches (``(batch,)`` int64 configuration indices).

    Shuffled epochs with the incomplete last batch dropped, like SDM's training; a batch size at
    least ``n_configs`` gives the whole set, in order, every step (full-batch descent).
    """
    if batch_size >= n_configs:
        everything = torch.arange(n_configs)
        while True:
            yield everything
    per_epoch = n_configs // batch_size
    while True:
        order = torch.randperm(n_configs, generator=generator)
        for index in range(per_epoch):
            yield order[index * batch_size : (index + 1) * batch_size]


@dataclass
class FitResult:
    """What a baseline fit returns.

    Attributes:
        theta: the estimate ``(a, b)`` in metres.
        seconds: wall time of the fit (setup included), seconds.
        evaluations: loss evaluations (gradient steps, or objective calls for CMA-ES).
        history: per step (or per CMA-ES generation) ``stage, loss, a, b``, as a dict of lists.
    """

    theta: tuple[float, float]
    seconds: float
    evaluations: int
    history: dict = field(default_factory=dict)

    def to_frame(self):
        import pandas as pd

        return pd.DataFrame(self.history)


def staged_adam(
    loss: Callable[[torch.Tensor, torch.Tensor, int, torch.Generator], torch.Tensor],
    n_configs: int,
    stages: Sequence[int],
    steps: int,
    lr: float,
    lr_decay: float,
    batch_size: int,
    seed: int,
    theta0: Sequence[float] = (0.0, 0.0),
    dtype: torch.dtype = torch.float64,
    device: torch.device | str | None = None,
) -> FitResult:
    """Adam on ``theta``, stage after stage (coarse to fine), the learning rate times ``lr_decay`` per stage.

    Within a stage the rate follows a cosine from the stage's rate down towards 0 (SGDR-style warm
    restarts), so each stage ends settled and the last one ends with steps far below ``lr``.

    Args:
        loss: ``loss(configs, theta, stage, generator)`` -> scalar tensor: the method's loss on
            mini-batch ``configs`` ((batch,) int64) at ``theta`` ((2,), requires grad).
        n_configs: size of the training set.
        stages: the stage labels in order (e.g. zoom levels ``s..0``), passed to ``loss``.
        steps: Adam steps per stage.
        lr: first stage's learning rate, metres (Adam's step is about ``lr`` per coordinate).
        lr_decay: factor per stage.
        batch_size: configurations per step (full batch when ``>= n_configs``).
        seed: seeds the mini-batches and any subsampling inside ``loss``.

    Returns:
        :class:`FitResult` (``seconds`` left 0: the caller times the whole fit).
    """
    generator = torch.Generator().manual_seed(int(seed))
    theta = torch.tensor([float(v) for v in theta0], dtype=dtype, device=device, requires_grad=True)
    optimizer = torch.optim.Adam([theta], lr=lr)
    batches = batch_orders(n_configs, batch_size, generator)
    history = {"stage": [], "loss": [], "a": [], "b": []}
    rate = lr
    for stage in stages:
        for step in range(steps):
            # Cosine within each stage (restarting at the stage's rate): the last steps of the last
            # stage are tiny, so theta settles instead of rattling by ~lr around the optimum.
            for group in optimizer.param_groups:
                group["lr"] = rate * 0.5 * (1.0 + math.cos(math.pi * step / steps))
            optimizer.zero_grad(set_to_none=True)
            value = loss(next(batches), theta, stage, generator)
            value.backward()
            if theta.grad is not None and bool(torch.isfinite(theta.grad).all()):
                optimizer.step()
            a, b = theta.detach().tolist()
            if not (math.isfinite(a) and math.isfinite(b)):
                raise SDMInputError(f"theta became non-finite at stage {stage} (lr {rate!r} too large?)")
            history["stage"].append(stage)
            history["loss"].append(float(value.detach()))
            history["a"].append(a)
            history["b"].append(b)
        rate *= lr_decay
    a, b = theta.detach().tolist()
    return FitResult((a, b), 0.0, len(history["loss"]), history)


def timed(fit: Callable[[], FitResult]) -> FitResult:
    """Run ``fit`` and store its wall time in the result."""
    start = time.perf_counter()
    result = fit()
    result.seconds = time.perf_counter() - start
    return result


# -- settings checks --------------------------------------------------------------------------------


def check_positive(settings, names: Sequence[str]) -> None:
    """:class:`SDMInputError` naming the field unless each of ``names`` is a positive finite number."""
    for name in names:
        value = getattr(settings, name)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            raise field_error(settings, name, f"must be a positive number, got {value!r}")


def check_positive_int(settings, names: Sequence[str], allow_zero: Sequence[str] = ()) -> None:
    """:class:`SDMInputError` naming the field unless each of ``names`` is a positive integer (or 0 if allowed)."""
    for name in names:
        value = getattr(settings, name)
        low = 0 if name in allow_zero else 1
        if isinstance(value, bool) or not isinstance(value, (int, float)) or int(value) != value or value < low:
            kind = "a non-negative" if low == 0 else "a positive"
            raise field_error(settings, name, f"must be {kind} integer, got {value!r}")


def field_error(settings, name: str, problem: str) -> SDMInputError:
    """An :class:`SDMInputError` about field ``name`` of a settings object; ``error.field`` holds the
    name and ``error.problem`` the text, so a caller can re-raise it under the config key it came from."""
    error = SDMInputError(f"{type(settings).__name__}.{name} {problem}")
    error.field, error.problem = name, problem
    return error


def sampled_pair(padded: PaddedSet, configs: torch.Tensor, theta: torch.Tensor, camera: Camera, max_points: int,
                 generator: torch.Generator):
    """The two point sets the Chamfer and Sinkhorn losses compare, for a batch of configurations.

    Up to ``max_points`` points per configuration, shifted by ``theta`` and projected, and up to
    ``max_points`` target pixel centres, each drawn without replacement from ``generator`` (points first).

    Returns:
        ``(screen, kept, centres, target_kept)``: ``(B, n, 2)`` projected points (screen pixels, float),
        ``(B, n)`` bool (a real point that lands on screen), ``(B, m, 2)`` target centres, ``(B, m)`` bool.
    """
    index, kept = subsample(padded.point_mask[configs], max_points, generator)
    points = padded.points[configs].gather(1, index.unsqueeze(-1).expand(-1, -1, 3))
    screen = project_shifted(points, theta, camera)
    kept = kept & on_screen(screen, camera.screen_shape)
    target_index, target_kept = subsample(padded.centre_mask[configs], max_points, generator)
    centres = padded.centres[configs].gather(1, target_index.unsqueeze(-1).expand(-1, -1, 2))
    return screen, kept, centres, target_kept

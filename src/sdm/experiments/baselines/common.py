"""What the baselines share: padded per-configuration tensors, projection of the shifted points,
mini-batches, settings checks and a staged Adam loop, for one run or for many runs as one program.

Every baseline sees exactly what SDM sees: the points ``Q`` of each configuration and its binary
target ``L`` (possibly noisy), and estimates ``theta = (a, b)`` in metres. The points of a
configuration at ``theta`` are ``P(Q + (a, b, 0))`` in screen pixels ``(row, col)``
(:meth:`sdm.Camera.project`); a point whose projection leaves the ``H x W`` screen has no
counterpart in the target (the target was built by dropping such points), so the point-set losses
ignore it at the current ``theta``.

Many runs (``fit_runs`` of each method): ``R`` independent fits on the same points with different
targets (e.g. the noisy targets of Table 3's runs) share each step's operations: ``theta`` is
``(R, 2)``, each run has its own Adam (:class:`RowAdam`) and its own generator drawing what its
single run draws in the same order (:func:`subsample_runs`, :func:`staged_adam_runs`), and the loss
is the sum of the runs' losses, so each run's gradient is its own. A run's result equals its single
run's to the bit (``tests/baselines/test_baselines_batched.py``).

Tensors live on the device of the training set's tensors; nothing is created on a fixed device
(random draws come from CPU generators, as in a single run, and are moved).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import torch

from ...batch import ConfigurationSet
from ...camera import Camera
from ...errors import SDMInputError
from ...sky import shift_vector


def pad_points(data: ConfigurationSet) -> tuple[torch.Tensor, torch.Tensor]:
    """Each configuration's points, zero-padded: ``(N, P, 3)`` float64 metres (padding rows ``(0, 0, 1)``, in front
    of the camera so that projecting them is finite) and the ``(N, P)`` bool mask of real points."""
    n_configs = len(data)
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
    return points, point_mask


def active_pixels(targets: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The active pixels of ``(N, H, W)`` bool targets, configuration by configuration.

    Returns:
        ``(active, counts, offsets)``: ``(K, 3)`` int64 ``(config, row, col)`` in config order
        (row-major within a configuration), ``(N,)`` int64 pixels per configuration and ``(N,)``
        int64 index of each configuration's first pixel in ``active``; on the targets' device.
    """
    active = targets.nonzero()
    counts = torch.bincount(active[:, 0], minlength=targets.shape[0])
    return active, counts, torch.cumsum(counts, 0) - counts


def pad_rows(values: torch.Tensor, counts: torch.Tensor, offsets: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Zero-padded ``(N, max(counts, 1), C)`` copy of ``(K, C)`` rows grouped by configuration, and its mask."""
    n_configs = counts.shape[0]
    config = torch.repeat_interleave(torch.arange(n_configs, device=values.device), counts)
    slot = torch.arange(values.shape[0], device=values.device) - offsets.index_select(0, config)
    width = max(int(counts.max()) if values.shape[0] else 0, 1)
    padded = torch.zeros(n_configs, width, values.shape[1], dtype=values.dtype, device=values.device)
    padded[config, slot] = values
    mask = torch.zeros(n_configs, width, dtype=torch.bool, device=values.device)
    mask[config, slot] = True
    return padded, mask


@dataclass(frozen=True)
class RunTargets:
    """The target pixels of ``R`` runs over the same ``N`` configurations, packed flat (no padding).

    Padding every run's target centres to the widest configuration would take ``R x N x T x 2``
    float64 (about 590 MB for 60 runs of 512 configurations with up to 1,200 pixels); the flat form
    takes 4 bytes per active pixel.

    Attributes:
        pixels: ``(K + 1, 2)`` int16 ``(row, col)`` of every run's active pixels, run by run, then
            configuration by configuration (row-major within one, as :func:`active_pixels` lists them);
            the last row is ``(0, 0)``, where padding slots point.
        counts: ``(R, N)`` int64 active pixels of each run's configuration.
        starts: ``(R, N)`` int64 index in ``pixels`` of each run's configuration's first pixel.
        widths: per run, the width of its centres padded alone (``max(counts[r], 1)``).
    """

    pixels: torch.Tensor
    counts: torch.Tensor
    starts: torch.Tensor
    widths: tuple[int, ...]


def pack_run_targets(targets: Sequence[torch.Tensor]) -> RunTargets:
    """:class:`RunTargets` of ``R`` ``(N, H, W)`` bool target tensors (same shape, same device)."""
    pixels, counts, starts, widths, base = [], [], [], [], 0
    device = targets[0].device
    for run_targets in targets:
        active, run_counts, offsets = active_pixels(run_targets)
        pixels.append(active[:, 1:].to(torch.int16))  # screens are far below 32,768 pixels a side
        counts.append(run_counts)
        starts.append(offsets + base)
        widths.append(max(int(run_counts.max()) if active.shape[0] else 0, 1))
        base += active.shape[0]
    pixels.append(torch.zeros(1, 2, dtype=torch.int16, device=device))  # where padding slots point
    return RunTargets(torch.cat(pixels), torch.stack(counts), torch.stack(starts), tuple(widths))


def check_runs(train_sets: Sequence[ConfigurationSet], seeds: Sequence[int]) -> None:
    """:class:`SDMInputError` unless the runs' sets share points, offsets and camera and one seed each."""
    if len(train_sets) == 0:
        raise SDMInputError("train_sets: need at least one run")
    if len(seeds) != len(train_sets):
        raise SDMInputError(f"seeds: one per run expected, got {len(seeds)} for {len(train_sets)} train_sets")
    first = train_sets[0]
    for index, other in enumerate(train_sets[1:], start=1):
        same = other.points is first.points or (
            other.points.shape == first.points.shape and bool(torch.equal(other.points, first.points)))
        if (not same or not torch.equal(other.offsets, first.offsets) or other.camera != first.camera
                or other.targets.shape != first.targets.shape):
            raise SDMInputError(f"train_sets[{index}]: runs must share points, offsets, camera and target shape "
                                "(only the targets may differ)")


def project_shifted(points: torch.Tensor, theta: torch.Tensor, camera: Camera) -> torch.Tensor:
    """Screen coordinates of ``points + (a, b, 0)``.

    Args:
        points: ``(..., 3)`` float64 metres, ``z > 0`` (checked when the set was built).
        theta: ``(2,)`` shift ``(a, b)`` in metres, same dtype, or ``(..., 2)`` broadcastable against
            ``points``' leading dimensions (one shift per run); may require grad.

    Returns:
        ``(..., 2)`` ``(row, col)`` in screen pixels, differentiable in ``theta``.
    """
    return camera.project(points + shift_vector(theta, points), validate=False)


def on_screen(screen: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """``(...)`` bool: continuous ``(..., 2)`` screen coordinates whose pixel is on the ``H x W`` screen."""
    height, width = shape
    row, col = screen.detach().unbind(-1)
    return (row >= 0) & (row < height) & (col >= 0) & (col < width)


def subsample_runs(mask: torch.Tensor, widths: Sequence[int], k: int,
                   generators: Sequence[torch.Generator]) -> tuple[torch.Tensor, torch.Tensor]:
    """Pick up to ``k`` random real entries per row, without replacement, for ``R`` runs at once.

    Run ``r`` alone would draw one float64 key per entry of its ``(B, widths[r])`` mask from its
    generator (nothing when ``k`` does not cut its width: it keeps its entries in order), give
    padding the key -1 and keep the ``k`` largest keys; here each run draws exactly those keys and
    one ``topk`` serves every run (``tests/baseline_reference.py`` holds the one-run version, and the
    tests hold the two equal).

    Args:
        mask: ``(R, B, W)`` bool, real entries; ``W >= max(widths)``, False beyond ``widths[r]``.
        widths: run ``r``'s own width (the width of its single-run mask).
        k: entries to keep per row; ``0`` keeps all.
        generators: ``R`` CPU generators.

    Returns:
        ``(index, kept)``: ``(R, B, n)`` int64 indices into the last axis of ``mask`` and bool, False
        where there is no real entry (their indices point at padding); ``n = min(k, W)``, or ``W``
        when ``k`` is 0. A run that did not draw lists its real entries first, in order.
    """
    n_runs, n_rows, width = mask.shape
    if k <= 0 or k >= width:  # nobody draws: every run's width is at most W <= k
        index = torch.arange(width, device=mask.device).expand(n_runs, n_rows, -1)
        return index, mask
    keys = []
    for run_width, generator in zip(widths, generators):
        if k < run_width:
            run_keys = torch.rand((n_rows, run_width), generator=generator, dtype=torch.float64)
        else:  # subsample keeps this run's entries in order without drawing: a descending ramp does that
            run_keys = torch.arange(run_width, 0, -1, dtype=torch.float64).expand(n_rows, -1)
        keys.append(torch.nn.functional.pad(run_keys, (0, width - run_width), value=-1.0))
    keys = torch.stack(keys).to(mask.device)
    keys = torch.where(mask, keys, torch.full_like(keys, -1.0))
    top, index = torch.topk(keys, k, dim=2)
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
        theta: the estimate ``(a, b)`` in metres; for a fit of per-row shifts (a parameter index,
            :mod:`sdm.sharing`), the ``(K, 2)`` float64 tensor of the rows' estimates.
        seconds: wall time of the fit (setup included), seconds; for a run of ``fit_runs``, the
            whole batched fit's wall time divided by its number of runs (:func:`timed_runs`).
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


class RowAdam:
    """``torch.optim.Adam`` (default betas and eps, no weight decay) on an ``(R, C)`` parameter,
    one independent Adam per row, each with its own step count, so a row can skip a step.

    Adam is elementwise, so rows never mix; the arithmetic is ``torch.optim.Adam``'s single-tensor
    step, operation for operation (the bias corrections in Python floats per row), so one row gives
    what ``torch.optim.Adam`` gives on that row alone, to the last bit (checked by the tests).
    """

    def __init__(self, param: torch.Tensor, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8):
        self.param, self.betas, self.eps = param, betas, eps
        self.exp_avg = torch.zeros_like(param, memory_format=torch.preserve_format).detach()
        self.exp_avg_sq = torch.zeros_like(self.exp_avg)
        self.counts = [0] * param.shape[0]

    @torch.no_grad()
    def step(self, lr: float, take: Sequence[bool]) -> None:
        """One step at rate ``lr`` for the rows where ``take`` is True (their gradient is in ``param.grad``)."""
        beta1, beta2 = self.betas
        grad = self.param.grad
        if grad is None or not any(take):
            return
        self.counts = [count + int(bool(go)) for count, go in zip(self.counts, take)]
        go = torch.tensor([bool(v) for v in take], device=self.param.device).unsqueeze(1)
        exp_avg = torch.where(go, self.exp_avg.lerp(grad, 1 - beta1), self.exp_avg)
        exp_avg_sq = torch.where(go, self.exp_avg_sq.mul(beta2).addcmul(grad, grad, value=1 - beta2), self.exp_avg_sq)
        counts = [max(count, 1) for count in self.counts]  # a row that never stepped is discarded below
        step_size = [lr / (1 - beta1**count) for count in counts]
        correction2_sqrt = [(1 - beta2**count) ** 0.5 for count in counts]
        like = dict(dtype=self.param.dtype, device=self.param.device)
        denom = (exp_avg_sq.sqrt() / torch.tensor(correction2_sqrt, **like).unsqueeze(1)).add_(self.eps)
        # addcdiv(param, exp_avg, denom, value=-step_size) computes param + (value * exp_avg) / denom
        moved = self.param + (torch.tensor([-v for v in step_size], **like).unsqueeze(1) * exp_avg) / denom
        self.param.copy_(torch.where(go, moved, self.param))
        self.exp_avg, self.exp_avg_sq = exp_avg, exp_avg_sq


def staged_adam_runs(
    loss: Callable[[torch.Tensor, torch.Tensor, int, Sequence[torch.Generator]], torch.Tensor],
    n_configs: int,
    stages: Sequence[int],
    steps: int,
    lr: float,
    lr_decay: float,
    batch_size: int,
    seeds: Sequence[int],
    theta0: Sequence[float] = (0.0, 0.0),
    dtype: torch.dtype = torch.float64,
    device: torch.device | str | None = None,
    table: bool = False,
) -> list[FitResult]:
    """Adam on ``theta``, stage after stage (coarse to fine), the learning rate times ``lr_decay`` per
    stage; ``R`` independent runs at once, one per seed.

    Within a stage the rate follows a cosine from the stage's rate down towards 0 (SGDR-style warm
    restarts), so each stage ends settled and the last one ends with steps far below ``lr``.

    The runs share nothing but the program: run ``r`` has its own ``theta[r]``, its own Adam state
    (:class:`RowAdam`), and its own generator seeded with ``seeds[r]`` that draws its mini-batches and
    (inside ``loss``) its subsamples in the order a single run draws them. The loss of a step is the
    sum of the runs' losses, so each row of the gradient is its own run's gradient; a run whose
    gradient is not finite skips that step alone.

    Args:
        loss: ``loss(configs, theta, stage, generators)`` -> ``(R,)`` tensor: run ``r``'s loss on its
            mini-batch ``configs[r]`` at ``theta[r]``; ``configs`` is ``(R, batch)`` int64 on
            ``device``, ``theta`` ``(R, 2)`` ``dtype`` metres (requires grad), ``generators`` the runs'.
        n_configs: size of the training set.
        stages: the stage labels in order (e.g. zoom levels ``s..0``), passed to ``loss``.
        steps: Adam steps per stage.
        lr: first stage's learning rate, metres (Adam's step is about ``lr`` per coordinate).
        lr_decay: factor per stage.
        batch_size: configurations per step and run (full batch when ``>= n_configs``).
        seeds: one per run; seeds its mini-batches and any subsampling inside ``loss``.
        theta0: every run's start ``(a, b)``, metres; with ``table``, a ``(K, 2)`` table of row shifts.
        dtype, device: of ``theta``.
        table: fit a table of ``K`` rows (parameters attached to points, :mod:`sdm.sharing`): ``theta``
            is ``(R, 2K)`` (run ``r``'s rows flattened, row ``k`` at ``[2k, 2k + 1]``), each run's Adam
            elementwise as before; the results' ``theta`` is a ``(K, 2)`` float64 tensor and their history
            holds ``stage, loss`` only.

    Returns:
        One :class:`FitResult` per run, in the order of ``seeds`` (``seconds`` left 0: the caller
        times the whole fit).

    Raises:
        SDMInputError: if a run's ``theta`` becomes non-finite (naming the run and stage).
    """
    generators = [torch.Generator().manual_seed(int(seed)) for seed in seeds]
    n_runs = len(generators)
    start = torch.as_tensor(theta0, dtype=torch.float64).reshape(-1).tolist() if table else theta0
    theta = torch.tensor([[float(v) for v in start]] * n_runs, dtype=dtype, device=device, requires_grad=True)
    adam = RowAdam(theta)
    batches = [batch_orders(n_configs, batch_size, generator) for generator in generators]
    histories = [{"stage": [], "loss": []} if table else {"stage": [], "loss": [], "a": [], "b": []}
                 for _ in range(n_runs)]
    rate = lr
    for stage in stages:
        for step in range(steps):
            # Cosine within each stage (restarting at the stage's rate): the last steps of the last
            # stage are tiny, so theta settles instead of rattling by ~lr around the optimum.
            step_lr = rate * 0.5 * (1.0 + math.cos(math.pi * step / steps))
            theta.grad = None
            configs = torch.stack([next(run_batches) for run_batches in batches]).to(theta.device)
            values = loss(configs, theta, stage, generators)
            values.sum().backward()
            take = [False] * n_runs if theta.grad is None else torch.isfinite(theta.grad).all(1).tolist()
            adam.step(step_lr, take)
            positions = torch.isfinite(theta.detach()).all(1).tolist() if table else theta.detach().tolist()
            for run, (position, value, history) in enumerate(zip(positions, values.detach().tolist(), histories)):
                if not (position if table else math.isfinite(position[0]) and math.isfinite(position[1])):
                    raise SDMInputError(f"theta of run {run} (seed {seeds[run]}) became non-finite at stage {stage} "
                                        f"(lr {rate!r} too large?)")
                history["stage"].append(stage)
                history["loss"].append(value)
                if not table:
                    history["a"].append(position[0])
                    history["b"].append(position[1])
        rate *= lr_decay
    if table:
        final = theta.detach().to(torch.float64).view(n_runs, -1, 2)
        return [FitResult(final[run].clone(), 0.0, len(history["loss"]), history)
                for run, history in enumerate(histories)]
    return [FitResult((history["a"][-1], history["b"][-1]) if history["a"] else tuple(float(v) for v in theta0),
                      0.0, len(history["loss"]), history) for history in histories]


def timed_runs(fit: Callable[[], list[FitResult]]) -> list[FitResult]:
    """Run ``fit`` (several runs as one program) and give each result the wall time divided by the runs.

    The runs share every step, so a run's own time is not measurable: ``seconds`` is the whole
    batched fit's wall time (setup included) over ``R``, the cost per run of the batch.
    """
    start = time.perf_counter()
    results = fit()
    seconds = (time.perf_counter() - start) / max(len(results), 1)
    for result in results:
        result.seconds = seconds
    return results


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


def sampled_pairs(points: torch.Tensor, point_mask: torch.Tensor, targets: RunTargets, configs: torch.Tensor,
                  theta: torch.Tensor, camera: Camera, max_points: int, generators: Sequence[torch.Generator]):
    """The two point sets the Chamfer and Sinkhorn losses compare, for ``R`` runs' mini-batches at once.

    Per configuration, up to ``max_points`` points, shifted by the run's theta and projected, and up
    to ``max_points`` target pixel centres ``(row + 0.5, col + 0.5)``, each drawn without replacement
    (:func:`subsample_runs`) from the run's own generator, points first: what the run would draw alone
    (``tests/baseline_reference.py``, held equal by the tests).

    Args:
        points, point_mask: the runs' shared ``(N, P, 3)`` float64 points (metres) and ``(N, P)``
            bool mask (:func:`pad_points`).
        targets: the runs' target pixels (:func:`pack_run_targets`).
        configs: ``(R, B)`` int64, run ``r``'s mini-batch.
        theta: ``(R, 2)`` float64 shifts, metres (may require grad).
        max_points: points (and target pixels) per configuration; 0 keeps all.
        generators: ``R`` CPU generators.

    Returns:
        ``(screen, kept, centres, target_kept)``: ``(R, B, n, 2)`` projected points (screen pixels,
        float64), ``(R, B, n)`` bool, ``(R, B, m, 2)`` target centres (float64), ``(R, B, m)`` bool;
        row ``[r, b]`` holds run ``r``'s draw for its ``b``-th configuration (padding after its entries).
    """
    n_runs, n_rows = configs.shape
    width = points.shape[1]
    mask = point_mask.index_select(0, configs.reshape(-1)).view(n_runs, n_rows, width)
    index, kept = subsample_runs(mask, [width] * n_runs, max_points, generators)
    flat = (configs.unsqueeze(-1) * width + index).reshape(-1)
    chosen = points.reshape(-1, 3).index_select(0, flat).view(*index.shape, 3)
    screen = project_shifted(chosen, theta.view(n_runs, 1, 1, -1), camera)
    kept = kept & on_screen(screen, camera.screen_shape)

    counts = targets.counts.gather(1, configs)  # (R, B)
    starts = targets.starts.gather(1, configs)
    target_width = max(targets.widths)
    slots = torch.arange(target_width, device=configs.device)
    target_mask = slots < counts.unsqueeze(-1)  # (R, B, T)
    target_index, target_kept = subsample_runs(target_mask, targets.widths, max_points, generators)
    # A padding slot may run past its configuration's pixels: point it at the spare last row (masked).
    flat = torch.where(target_kept, starts.unsqueeze(-1) + target_index,
                       torch.full_like(target_index, targets.pixels.shape[0] - 1))
    centres = targets.pixels.index_select(0, flat.reshape(-1)).to(points.dtype).view(*flat.shape, 2) + 0.5
    return screen, kept, centres, target_kept


def mean_of_usable(value: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
    """Each run's loss: the mean of its mini-batch's finite per-configuration losses.

    Args:
        value: ``(R, B)`` per-configuration losses, NaN where a configuration has nothing to compare.
        theta: ``(R, 2)`` the runs' shifts.

    Returns:
        ``(R,)``; a run with no finite entry gets ``0 * sum(theta[r])`` (zero loss, zero gradient),
        as a single run does.
    """
    usable = torch.isfinite(value)
    count = usable.sum(1)
    total = torch.where(usable, value, torch.zeros_like(value)).sum(1)
    mean = total / count.clamp(min=1).to(value.dtype)
    return torch.where(count > 0, mean, theta.sum(1).to(value.dtype) * 0.0)

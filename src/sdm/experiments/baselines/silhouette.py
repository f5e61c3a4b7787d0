"""Soft-silhouette image loss: the differentiable-rendering way (SoftRas / PyTorch3D soft points).

Each shifted point, projected onto the screen, is splatted as an isotropic Gaussian
``w = exp(-d^2 / (2 sigma^2))`` (``d``: distance from the point to a cell centre); a cell's soft
silhouette is ``S = 1 - prod_points (1 - w)``, computed as ``-expm1(sum log1p(-w))`` so that the
product of hundreds of factors neither underflows nor loses the gradient. ``S`` is compared with
the target by the soft IoU loss ``1 - sum(S T) / sum(S + T - S T)`` per configuration (SoftRas's
silhouette loss), averaged over the mini-batch.

Why soft IoU rather than L2: a target covers about 2 % of the screen, so a summed L2 loss is
dominated by the many empty cells and its scale depends on how many cars a configuration has;
the IoU is a ratio, between 0 and 1 for every configuration, which weighs configurations alike and
keeps one learning rate good for all of them and for every level. ``loss="l2"`` (mean squared
error per cell) is there to compare.

Coarse to fine, in step with SDM's zoom levels ``s..0``: at level ``k`` the screen is cut into
blocks of ``2^k x 2^k`` pixels, the target is the level's zoomed-out target (the block is on when
any of its pixels is, as SDM's pyramid), and ``sigma`` is measured in blocks, so the Gaussian is
``sigma 2^k`` pixels wide: wide at the start (a basin of attraction several pixels across), sharp
at the end. Memory stays bounded because each point only touches the ``(2R+1)^2`` blocks around
it, ``R = ceil(3 sigma)`` (weights beyond three sigma are below 1.2 %, and are dropped).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch

from ...batch import ConfigurationSet
from ...camera import Camera
from ...errors import SDMInputError
from ...sharing import check_param_index, check_theta, point_shifts
from ...zoom import check_divisible
from .common import (
    FitResult, check_positive, check_positive_int, check_runs, field_error, project_shifted, staged_adam_runs,
    timed_runs,
)


@dataclass(frozen=True)
class SilhouetteSettings:
    """Hyper-parameters of the soft-silhouette fit.

    Attributes:
        lr: Adam's learning rate at the coarsest level, metres.
        steps: Adam steps per level.
        sigma: Gaussian width in blocks of the current level (``sigma 2^k`` screen pixels at level ``k``).
        s: coarsest level (blocks of ``2^s`` pixels); levels ``s..0``.
        lr_decay: learning-rate factor per level.
        batch_size: configurations per step.
        loss: ``"iou"`` (soft IoU, default) or ``"l2"`` (mean squared error per cell).
        float32: splat in float32 (half the cost of float64; theta and projections stay float64).
    """

    lr: float = 0.1
    steps: int = 36
    sigma: float = 0.5
    s: int = 3
    lr_decay: float = 0.5
    batch_size: int = 16
    loss: str = "iou"
    float32: bool = True

    def __post_init__(self) -> None:
        check_positive(self, ("lr", "sigma", "lr_decay"))
        check_positive_int(self, ("steps", "batch_size"))
        check_positive_int(self, ("s",), allow_zero=("s",))
        if self.loss not in ("iou", "l2"):
            raise field_error(self, "loss", f"must be 'iou' or 'l2', got {self.loss!r}")


def runs_per_splat(zoom: int) -> int:
    """Runs splatted together at zoom ``zoom``: about 256k cells (1 MB of float32) per pass.

    The splat and the soft IoU are dense over the cells; measured on one thread (level-2 noise
    runs of the default data), batching every run's level-0 silhouettes at once ran about twice
    slower per run than one run after another (the tensors leave the cache), while a few runs
    at a time at the coarse levels, where a run has 512 to 2,048 cells per image, shares the
    per-operation overhead.
    """
    return max(1, 4**zoom // 2)


def soft_silhouette(screen: torch.Tensor, config: torch.Tensor, n_configs: int, zoom: int, sigma: float,
                    shape: tuple[int, int]) -> torch.Tensor:
    """Soft silhouettes of a batch of point sets at zoom level ``zoom``.

    Args:
        screen: ``(P, 2)`` float points ``(row, col)`` in screen pixels (may require grad); the
            splatting runs in this dtype (float32 halves the cost and is ample for weights).
        config: ``(P,)`` int64 batch-local configuration of each point, in ``[0, n_configs)``.
        n_configs: configurations in the batch.
        zoom: zoom level ``k``: blocks of ``2^k`` pixels.
        sigma: Gaussian width in blocks, positive.
        shape: full screen ``(H, W)``, divisible by ``2^k``.

    Returns:
        ``(n_configs, H / 2^k, W / 2^k)`` soft silhouette in ``[0, 1)``, dtype of ``screen``.
    """
    if not sigma > 0:
        raise SDMInputError(f"sigma must be positive, got {sigma!r}")
    block = 1 << zoom
    height, width = shape[0] // block, shape[1] // block
    position = screen / block  # (P, 2) in blocks
    nearest = torch.floor(position.detach()).to(torch.int64)
    n_points = nearest.shape[0]
    # The window: the n = m x m blocks within R = ceil(3 sigma) in each direction (rows outer, columns
    # inner). Its integer parts are built per row and per column, (P, m) each, and combined to
    # (P, m, m) = (P, n) only at the end: the same cells as offsets of all n, at a fraction of the passes.
    reach = max(1, math.ceil(3.0 * sigma))
    steps = torch.arange(-reach, reach + 1, device=screen.device)
    rows, cols = nearest[:, :1] + steps, nearest[:, 1:] + steps  # (P, m) block rows and columns of the window
    keep = ((rows >= 0) & (rows < height)).unsqueeze(2) & ((cols >= 0) & (cols < width)).unsqueeze(1)
    keep = keep.view(n_points, -1)  # (P, n)
    # Cells off the grid are clamped onto it and contribute log(1 - 0) = 0: dense ops, no boolean
    # indexing (which costs more than the splat itself).
    row_start = (config.unsqueeze(1) * height + rows.clamp(0, height - 1)) * width  # (P, m)
    flat = (row_start.unsqueeze(2) + cols.clamp(0, width - 1).unsqueeze(1)).view(n_points, -1)  # (P, n)
    centres = torch.stack(torch.broadcast_tensors(rows.to(screen.dtype).unsqueeze(2) + 0.5,
                                                  cols.to(screen.dtype).unsqueeze(1) + 0.5), -1)  # (P, m, m, 2)
    delta = centres.view(n_points, -1, 2) - position.unsqueeze(1)  # (P, n, 2)
    weight = torch.exp((delta * delta).sum(-1) * (-0.5 / (sigma * sigma))) * keep
    # log(1 - w), with w kept below 1 so that a point sitting exactly on a cell centre stays finite.
    log_empty = torch.log1p(-weight.clamp(max=1.0 - 1e-6))
    total = torch.zeros(n_configs * height * width, dtype=screen.dtype, device=screen.device)
    total = total.index_add(0, flat.reshape(-1), log_empty.reshape(-1))
    return (-torch.expm1(total)).view(n_configs, height, width)


def image_loss(silhouette: torch.Tensor, target: torch.Tensor, kind: str = "iou") -> torch.Tensor:
    """Scalar loss between ``(B, h, w)`` soft silhouettes and ``(B, h, w)`` targets, mean over the batch.

    ``"iou"``: ``1 - sum(S T) / sum(S + T - S T)`` per image (an image whose silhouette and target
    are both empty counts 0). ``"l2"``: mean of ``(S - T)^2`` per image.
    """
    return image_losses(silhouette, target, kind).mean()


def image_losses(silhouette: torch.Tensor, target: torch.Tensor, kind: str = "iou") -> torch.Tensor:
    """``(B,)`` per-image losses of :func:`image_loss` (dtype of ``silhouette``)."""
    target = target.to(silhouette.dtype)
    if kind == "l2":
        return ((silhouette - target) ** 2).mean(dim=(1, 2))
    intersection = (silhouette * target).sum(dim=(1, 2))
    union = (silhouette + target - silhouette * target).sum(dim=(1, 2))
    return 1.0 - intersection / union.clamp(min=1e-12)


def settings_dtype(settings: SilhouetteSettings) -> torch.dtype:
    """The dtype the splatting runs in (theta and the projection stay float64)."""
    return torch.float32 if settings.float32 else torch.float64


def fit(train_set: ConfigurationSet, settings: SilhouetteSettings = SilhouetteSettings(), seed: int = 0,
        camera: Camera | None = None, theta0=(0.0, 0.0), param_index=None) -> FitResult:
    """Estimate ``theta`` by Adam on the soft-silhouette loss, levels ``s..0``: one run of :func:`fit_runs`.

    Args:
        train_set: configurations (points ``Q``, targets ``L``).
        settings: hyper-parameters.
        seed: seeds the mini-batches.
        param_index: rows moving each point (:func:`fit_runs`); ``theta0`` is then the ``(K, 2)`` start.

    Returns:
        :class:`~sdm.experiments.baselines.common.FitResult`; history stages are the zoom levels.
    """
    return fit_runs([train_set], settings, [seed], camera, theta0, param_index)[0]


def fit_runs(train_sets: Sequence[ConfigurationSet], settings: SilhouetteSettings = SilhouetteSettings(),
             seeds: Sequence[int] = (0,), camera: Camera | None = None, theta0=(0.0, 0.0),
             param_index=None) -> list[FitResult]:
    """``R`` independent soft-silhouette fits as one program: run ``r`` is ``fit(train_sets[r], settings, seeds[r])``.

    Each step splats the runs' mini-batches as one batch of ``R x batch_size`` silhouettes (run
    ``r``'s points shifted by its own ``theta[r]``), which shares the per-operation overhead of a
    single run's steps (on one CPU core no faster per run: the splatting arithmetic dominates,
    ``benchmarks/speed/bench_baselines.py``); each run keeps its own theta, Adam state and generator
    (:func:`~sdm.experiments.baselines.common.staged_adam_runs`).

    Args:
        train_sets: ``R`` sets with the same points, offsets and camera (tensors on one device),
            differing only in their targets. Each set's zoom pyramid is built (and cached in the
            set, as ``fit`` does): levels 1..s add about 5.5 MB per run to its 16.8 MB of targets
            (512 configurations of 128 x 256).
        settings: shared by every run.
        seeds: ``R`` seeds; ``seeds[r]`` draws run ``r``'s mini-batches as ``fit`` does.
        camera: default the sets' camera.
        theta0: every run's start ``(a, b)``, metres; with ``param_index``, the ``(K, 2)`` table of rows.
        param_index: ``None`` (one shift for every point: the paper's case, the path of Table 3), or the
            rows moving each point, ``(P,)`` or ``(P, G)`` (:mod:`sdm.sharing`): each point is shifted by
            the sum of its rows of its run's ``theta`` and each run fits a ``(K, 2)`` table. A row's
            gradient comes from its configurations alone, so a mini-batch moves only the rows of its
            configurations (and Adam's momentum the others): fit per-row tables with ``batch_size`` at
            least the number of configurations (every row a gradient every step).

    Returns:
        One :class:`~sdm.experiments.baselines.common.FitResult` per run (``theta`` ``(K, 2)`` with ``param_index``);
        ``seconds`` is the batched fit's wall time divided by ``R`` (its cost per run).

    Raises:
        SDMInputError: naming ``param_index`` (out of range, negative, wrong length, a row without points)
            or ``theta0`` (not ``(K, 2)``).
    """
    check_runs(train_sets, seeds)
    camera = camera or train_sets[0].camera
    first = train_sets[0]
    index = None
    if param_index is not None:
        theta0 = check_theta(theta0, name="theta0")
        index = check_param_index(param_index, first, theta0.shape[0]).to(first.device)

    def run() -> list[FitResult]:
        check_divisible(camera.screen_shape, settings.s)
        pyramids = [train_set.pyramid(settings.s) for train_set in train_sets]

        def chunk_loss(configs, theta, zoom, chunk_pyramids):
            n_runs, n_rows = configs.shape
            rows, local = first.rows(configs.reshape(-1))
            run_of_row = torch.div(local, n_rows, rounding_mode="floor")
            if index is None:  # one shift per run
                shift = theta.index_select(0, run_of_row)
            else:  # each point its rows' sum, of its run's table
                shift = point_shifts(theta.view(n_runs, -1, 2), index.index_select(0, rows), runs=run_of_row)
            screen = project_shifted(first.points.index_select(0, rows), shift, camera)
            silhouette = soft_silhouette(screen.to(settings_dtype(settings)), local, n_runs * n_rows, zoom,
                                         settings.sigma, camera.screen_shape)
            target = torch.cat([pyramid[zoom].index_select(0, run_configs)
                                for pyramid, run_configs in zip(chunk_pyramids, configs)])
            return image_losses(silhouette, target, settings.loss).view(n_runs, n_rows).mean(1)

        def loss(configs, theta, zoom, generators):
            # The splat and the image loss are dense over the screen's cells: a few runs at a time
            # keep those tensors in cache; the whole batch at once is slower than one run after another.
            chunk = runs_per_splat(zoom)
            return torch.cat([chunk_loss(configs[first_run:first_run + chunk], theta[first_run:first_run + chunk],
                                         zoom, pyramids[first_run:first_run + chunk])
                              for first_run in range(0, len(pyramids), chunk)])

        return staged_adam_runs(loss, len(first), range(settings.s, -1, -1), settings.steps, settings.lr,
                                settings.lr_decay, settings.batch_size, seeds, theta0, device=first.points.device,
                                table=index is not None)

    return timed_runs(run)

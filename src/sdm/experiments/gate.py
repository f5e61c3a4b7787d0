"""What theta*'s prior tells SDM's rows on Table 6 (docs/method/objects.md): where each row starts training, its
first zoom (:func:`prior_zooms`, "Each row's first level") and the prior gate, a check after any method that returns
to its start every unit whose estimate travelled implausibly far under the prior (:func:`prior_gate`, "The prior
gate")."""
from __future__ import annotations

import torch

from .. import sharing as S
from ..batch import ConfigurationSet
from ..errors import SDMInputError


def prior_sd(sharing: S.Sharing, truth: S.TruthDistribution) -> torch.Tensor:
    """Each row's prior spread per axis (metres), as :func:`sdm.sharing.draw_truth` draws it: ``camera_sd`` for a
    configuration's or a camera's row, ``car_sd`` for a car's, ``residual_sd`` for a car's residual
    (``camera+car``).

    Returns:
        ``(K,)`` float64 on the CPU.
    """
    if sharing.name == "configuration":
        return torch.full((sharing.n_rows,), float(truth.camera_sd), dtype=torch.float64)
    if sharing.name == "car":
        return torch.full((sharing.n_rows,), float(truth.car_sd), dtype=torch.float64)
    if sharing.name == "camera+car":
        is_car = sharing.rows[:, 1].cpu() != S.NO_INDEX
        return torch.where(is_car, float(truth.residual_sd), float(truth.camera_sd)).to(torch.float64)
    raise SDMInputError(f"sharing must be one of {', '.join(S.ROW_SHARINGS)}, got {sharing.name!r}")


def prior_gate(theta: torch.Tensor, start: torch.Tensor, sd: torch.Tensor, gate: float
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """The prior gate: every row that ends farther than ``gate * sd`` from its start is returned to its start.

    A row's travel is the Euclidean norm of ``theta - start``. Under the prior a row's true shift lies farther than
    ``g`` standard deviations from its prior mean with probability ``exp(-g^2 / 2)`` (1.1 % at ``g = 3``), so a
    row that travels that far from a start near the mean has most likely been pulled onto pixels that are not its
    own (docs/method/objects.md, "The prior gate").

    Args:
        theta: ``(K, 2)`` metres, the rows' estimates.
        start: ``(K, 2)`` metres, the rows' starts (same device).
        sd: ``(K,)`` metres, each row's prior spread per axis (:func:`prior_sd`).
        gate: a positive number of standard deviations.

    Returns:
        ``(gated (K, 2) float64, returned (K,) bool)``, on ``theta``'s device: the gated rows and which were returned.
    """
    if isinstance(gate, bool) or not isinstance(gate, (int, float)) or not gate > 0:
        raise SDMInputError(f"gate must be a positive number of standard deviations, got {gate!r}")
    if theta.shape != start.shape or theta.dim() != 2 or theta.shape[1] != 2 or sd.shape != theta.shape[:1]:
        raise SDMInputError(f"theta and start must be (K, 2) and sd (K,), got {tuple(theta.shape)}, "
                            f"{tuple(start.shape)} and {tuple(sd.shape)}")
    theta, start = theta.to(torch.float64), start.to(theta.device, torch.float64)
    returned = (theta - start).norm(dim=1) > float(gate) * sd.to(theta.device, torch.float64)
    return torch.where(returned.unsqueeze(1), start, theta), returned


def prior_zooms(data: ConfigurationSet, sharing: S.Sharing, sd: torch.Tensor, s: int) -> torch.Tensor:
    """Each row's first (coarsest) trained zoom (:func:`sdm.train.train_runs` ``row_zoom``): the finest zoom whose
    block is at least the row's prior spread in screen columns, ``clamp(ceil(log2(sd_k / dx_k)), 0, s)``.

    ``dx_k`` is the width in metres of one screen column (the screen's coarser axis) at the mean depth of row
    ``k``'s points (:meth:`sdm.camera.Camera.metres_per_screen_pixel`). At a coarser zoom a row's disc and its target
    share a block for most draws of theta*, so the row gets no pull of its own, only the other rows' targets'
    (docs/method/objects.md, "Each row's first level").

    Args:
        data: the configurations whose points ``sharing`` indexes (its camera and screen).
        sharing: the rows; a point moved by several rows (``camera+car``) counts in each.
        sd: ``(K,)`` metres, each row's prior spread per axis (:func:`prior_sd`).
        s: the schedule's coarsest zoom, a non-negative integer.

    Returns:
        ``(K,)`` int64 on the CPU, in ``0 .. s``.

    >>> from sdm import ConfigurationSet, build_configuration
    >>> near = build_configuration(torch.tensor([[-3.0, 2.5, 10.0]], dtype=torch.float64))  # a car at 10 m
    >>> far = build_configuration(torch.tensor([[-3.0, 2.5, 80.0]], dtype=torch.float64))  # a car at 80 m
    >>> data = ConfigurationSet.from_configurations([near, far])
    >>> rows = S.sharing("configuration", data)
    >>> sd = torch.full((2,), 0.15, dtype=torch.float64)  # 2.6 columns of 128 x 256 at 10 m, 0.33 at 80 m
    >>> prior_zooms(data, rows, sd, 6).tolist()
    [2, 0]
    """
    if isinstance(s, bool) or not isinstance(s, int) or s < 0:
        raise SDMInputError(f"s must be a non-negative integer zoom, got {s!r}")
    if sd.shape != (sharing.n_rows,) or not bool((sd > 0).all()):
        raise SDMInputError(f"sd must be {sharing.n_rows} positive spreads (one per row), got {tuple(sd.shape)}")
    index = sharing.param_index.cpu()
    index = index.unsqueeze(1) if index.dim() == 1 else index
    depth = data.points[:, 2].detach().to("cpu", torch.float64)
    total = torch.zeros(sharing.n_rows, dtype=torch.float64)
    count = torch.zeros(sharing.n_rows, dtype=torch.float64)
    for column in index.unbind(1):
        moved = column != S.NO_INDEX
        total.index_add_(0, column[moved], depth[moved])
        count.index_add_(0, column[moved], torch.ones_like(depth[moved]))
    column_width = data.camera.metres_per_screen_pixel(total / count.clamp(min=1))[1]
    zoom = torch.ceil(torch.log2(sd.to(torch.float64) / column_width))
    return zoom.clamp(0, s).to(torch.int64)

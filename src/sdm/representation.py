"""2D representations of fragments and the ``rmin`` aggregation.

A *fragment* is a 3D point with a positive rendering value ``r``. The 2D
representation of a set of fragments assigns each screen pixel the ``rmin`` of
the fragments that project into it: among those with the smallest positive
depth, the smallest ``r``; 0 where nothing lands (paper, section 2).

When two fragments tie on both depth and ``r`` (common in the Sky data: every
pixel of one circle has the same depth), the one with the smaller index wins.
The choice is invisible in the representation's values but decides *which*
point survives, so it is fixed here once and used everywhere.
"""
from __future__ import annotations

import torch

from .camera import Camera
from .errors import SDMInputError

#: The ``rmin`` priority of "no fragment": larger than every real rank, so any fragment beats it.
NO_RANK = torch.iinfo(torch.int64).max


def priority_rank(depth: torch.Tensor, tiebreak: torch.Tensor | None = None) -> torch.Tensor:
    """Rank of each fragment in ``rmin`` order: depth, then ``tiebreak``, then index.

    Args:
        depth: ``(K,)`` depths in metres.
        tiebreak: optional ``(K,)`` secondary key (the rendering value ``r``).

    Returns:
        ``(K,)`` int64 ranks, a permutation of ``0..K-1``; rank 0 wins everything.
    """
    order = torch.arange(depth.numel(), device=depth.device)
    if tiebreak is not None:
        order = order[torch.sort(tiebreak[order], stable=True).indices]
    order = order[torch.sort(depth[order], stable=True).indices]
    rank = torch.empty_like(order)
    rank[order] = torch.arange(order.numel(), device=depth.device)
    return rank


def first_by_rank(cell: torch.Tensor, rank: torch.Tensor, n_cells: int) -> torch.Tensor:
    """Which fragments win their cell.

    Args:
        cell: ``(K,)`` int64 cell index of each fragment, in ``[0, n_cells)``.
        rank: ``(K,)`` int64 priority (lower wins), distinct within a cell.
        n_cells: number of cells.

    Returns:
        ``(K,)`` bool, true for exactly one fragment per occupied cell.
    """
    best = torch.full((n_cells,), NO_RANK, dtype=torch.int64, device=cell.device)
    best.scatter_reduce_(0, cell, rank, reduce="amin")
    return best[cell] == rank


def inside(pixels: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """``(...,)`` bool: integer ``(..., 2)`` pixels (or blocks) inside an ``height x width`` grid.

    Four comparisons with Python scalars (no constant tensor, so nothing to keep
    per device); measured on the SDM layer's hot path to be as fast as the
    branch-free product form it replaced.
    """
    row, col = pixels[..., 0], pixels[..., 1]
    return (row >= 0) & (row < height) & (col >= 0) & (col < width)


def screen_pixels(screen: torch.Tensor, camera: Camera) -> tuple[torch.Tensor, torch.Tensor]:
    """Integer pixel of continuous screen coordinates, and whether it is on screen.

    Args:
        screen: ``(..., 2)`` screen coordinates ``(row, col)``.

    Returns:
        ``(pixels, on_screen)``: ``(..., 2)`` int64 ``floor(screen)`` and ``(...)`` bool.
    """
    pixels = torch.floor(screen).to(torch.int64)
    height, width = camera.screen_shape
    return pixels, inside(pixels, height, width)


def render_rmin(points: torch.Tensor, values: torch.Tensor, camera: Camera) -> torch.Tensor:
    """The ``rmin`` 2D representation of fragments ``(points, values)``.

    Fragments that fall off screen are ignored (all points must be in front of
    the camera).

    Args:
        points: ``(K, 3)`` camera-frame points in metres, ``z > 0``.
        values: ``(K,)`` positive rendering values ``r``.
        camera: camera and screen.

    Returns:
        ``(H, W)`` tensor (dtype of ``values``): ``r`` of the winning fragment, 0 where empty.
    """
    if points.ndim != 2:
        raise SDMInputError(f"points must have shape (K, 3), got {tuple(points.shape)}")
    if values.shape != points.shape[:1]:
        raise SDMInputError(f"values must have shape ({points.shape[0]},), got {tuple(values.shape)}")
    if bool((values <= 0).any()):
        raise SDMInputError("fragment values r must be positive")
    height, width = camera.screen_shape
    image = torch.zeros(height * width, dtype=values.dtype, device=values.device)
    if points.shape[0] == 0:
        return image.view(height, width)
    pixels, on_screen = screen_pixels(camera.project(points), camera)
    pixels, depth, values = pixels[on_screen], points[on_screen, 2], values[on_screen]
    cell = pixels[:, 0] * width + pixels[:, 1]
    winners = first_by_rank(cell, priority_rank(depth, values), height * width)
    image[cell[winners]] = values[winners]
    return image.view(height, width)


def occupancy(pixels: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """Binary mask of integer pixels; off-screen ones are dropped.

    Args:
        pixels: ``(K, 2)`` int64 ``(row, col)``.
        shape: the screen ``(H, W)``.

    Returns:
        ``(H, W)`` bool.
    """
    height, width = shape
    mask = torch.zeros(height, width, dtype=torch.bool, device=pixels.device)
    kept = pixels[inside(pixels, height, width)]
    mask[kept[:, 0], kept[:, 1]] = True
    return mask

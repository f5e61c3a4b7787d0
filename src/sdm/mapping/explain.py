"""One point through one SDM level, every intermediate exposed (Figures 2 and 3 of the paper)."""
from __future__ import annotations

import torch

from ..camera import APOLLO_CAMERA_5, Camera, check_points
from ..errors import SDMInputError
from ..zoom import zoom_out

_OFFSETS = torch.tensor([(dk, dl) for dk in (-1, 0, 1) for dl in (-1, 0, 1)], dtype=torch.int64)


def explain_point(
    point: torch.Tensor,
    pixel: tuple[int, int],
    target: torch.Tensor,
    level: int = 0,
    c: float = 20.0,
    camera: Camera = APOLLO_CAMERA_5,
) -> dict:
    """Forward and backward of one SDM level for a single point.

    Args:
        point: ``(3,)`` the (shifted) point in metres.
        pixel: ``(row, col)`` the pixel it sits in at this level's input.
        target: ``(H, W)`` bool target at full resolution.
        level: zoom level ``k`` (blocks of ``2^k`` pixels).
        c: kernel shape constant, 1/metres (finite, so the kernel is visibly soft).
        camera: camera and screen.

    Returns:
        dict with ``block`` (input block, ``(2,)``), ``adjustments`` ``(3, 3, 3)``
        XY-adjustment points (metres), ``screen`` ``(3, 3, 2)`` their screen
        coordinates, ``kernel`` ``(3, 3)`` the softmax ``D``, ``landing`` ``(2,)``
        the landing block (nearest adjustment), ``matched`` (bool), ``active``
        ``(3, 3)`` bool target blocks of the window, ``pull`` ``(2,)`` the
        dynamic gradient flow on ``(x, y)``, and ``point_screen`` ``(2,)``.
    """
    point = torch.as_tensor(point, dtype=torch.float64)
    check_points(point, "point")
    if target.shape != camera.screen_shape:
        raise SDMInputError(f"target must have shape {camera.screen_shape}, got {tuple(target.shape)}")
    block_size = 1 << level
    block = torch.tensor(pixel, dtype=torch.int64) >> level
    window = block + _OFFSETS  # (9, 2) blocks
    centres = (window.to(torch.float64) + 0.5) * block_size
    adjustments = camera.backproject(centres, point[2].expand(9))
    distance = (point[:2] - adjustments[:, :2]).norm(dim=-1)
    kernel = torch.softmax(-c * distance, dim=0)
    nearest = int(distance.argmin())
    zoomed = zoom_out(target, level)
    inside = (window >= 0).all(1) & (window[:, 0] < zoomed.shape[0]) & (window[:, 1] < zoomed.shape[1])
    active = torch.zeros(9, dtype=torch.bool)
    active[inside] = zoomed[window[inside, 0], window[inside, 1]]
    matched = bool(active[nearest])
    pulling = active.clone()
    pulling[nearest] = False
    if matched or not bool(inside[nearest]):
        pulling[:] = False
    pull = (torch.sign(point[:2] - adjustments[:, :2]) * pulling[:, None]).sum(0)
    return {
        "block": block,
        "adjustments": adjustments.view(3, 3, 3),
        "screen": centres.view(3, 3, 2),
        "kernel": kernel.view(3, 3),
        "landing": window[nearest],
        "matched": matched,
        "active": active.view(3, 3),
        "pull": pull,
        "point_screen": camera.project(point),
    }

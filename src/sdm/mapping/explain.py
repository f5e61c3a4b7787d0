"""One point through one SDM zoom, every intermediate exposed (Figures 2 and 3 of the paper)."""
from __future__ import annotations

import torch

from ..camera import APOLLO_CAMERA_5, Camera, check_points
from ..errors import SDMInputError
from ..zoom import zoom_out
from .flow import block_window, dynamic_flow, nine


def explain_point(
    point: torch.Tensor,
    pixel: tuple[int, int],
    target: torch.Tensor,
    zoom: int = 0,
    sharpness: float = 20.0,
    camera: Camera = APOLLO_CAMERA_5,
) -> dict:
    """Forward and backward of one SDM zoom for a single point.

    The landing block is the nearest XY-adjustment (the forward's choice); the
    pull is :func:`~sdm.mapping.flow.dynamic_flow`, the rule the layer's backward uses.

    Args:
        point: ``(3,)`` the (shifted) point in metres; its device is used throughout.
        pixel: ``(row, col)`` the pixel it sits in at this zoom's input.
        target: ``(H, W)`` bool target at full resolution, on the device of ``point``.
        zoom: the zoom ``k`` (blocks of ``2^k`` pixels).
        sharpness: the kernel's sharpness, the paper's ``c``, 1/metres (finite, so the kernel is visibly soft).
        camera: camera and screen.

    Returns:
        dict with ``block`` (input block, ``(2,)``), ``adjustments`` ``(3, 3, 3)``
        XY-adjustment points (metres), ``screen`` ``(3, 3, 2)`` their screen
        coordinates, ``kernel`` ``(3, 3)`` the softmax ``D``, ``landing`` ``(2,)``
        the landing block (nearest adjustment), ``matched`` (bool), ``active``
        ``(3, 3)`` bool target blocks of the window, ``pull`` ``(2,)`` the
        dynamic gradient flow on ``(x, y)``, and ``point_screen`` ``(2,)``.
    """
    point = point.to(torch.float64) if isinstance(point, torch.Tensor) else torch.tensor(point, dtype=torch.float64)
    check_points(point, "point")
    if target.shape != camera.screen_shape:
        raise SDMInputError(f"target must have shape {camera.screen_shape}, got {tuple(target.shape)}")
    device = point.device
    block = torch.tensor(pixel, dtype=torch.int64, device=device) >> zoom
    zoomed, config = zoom_out(target, zoom), torch.zeros(1, dtype=torch.int64, device=device)
    window = block_window(block[None], config, zoomed[None], zoom, torch.float64)  # the flow's window, p = 1
    blocks, centres = window.blocks()[0], nine(window.centres)[0]  # (9, 2) blocks, (9, 2) screen pixels
    adjustments = camera.backproject(centres, point[2].expand(9))
    distance = (point[:2] - adjustments[:, :2]).norm(dim=-1)
    kernel = torch.softmax(-sharpness * distance, dim=0)
    nearest = int(distance.argmin())
    in_grid, active = window.on_grid[0], window.active[0]
    landing = blocks[nearest]
    flow, _, matched = dynamic_flow(
        camera.project(point)[None], point[2:], config, in_grid[nearest : nearest + 1], block[None], landing[None],
        zoomed[None], zoom, camera,
    )
    return {
        "block": block,
        "adjustments": adjustments.view(3, 3, 3),
        "screen": centres.view(3, 3, 2),
        "kernel": kernel.view(3, 3),
        "landing": landing,
        "matched": bool(matched[0]),
        "active": active.view(3, 3),
        "pull": flow[0],
        "point_screen": camera.project(point),
    }

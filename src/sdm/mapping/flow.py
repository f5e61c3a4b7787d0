"""The dynamic gradient flow (paper, eq. 19): one rule, used by every SDM path.

Both implementations of the layer (:mod:`~sdm.mapping.fast` and the dense grid
reference :mod:`~sdm.mapping.dense`) and the single-point explainer
(:func:`~sdm.mapping.explain.explain_point`) decide *where* each point lands;
what the backward pass does with that is decided here, once (docs/method.md,
"Backward pass").
"""
from __future__ import annotations

import functools

import torch

from ..camera import Camera
from ..representation import inside

#: The 3x3 kernel window, ``(drow, dcol)`` in row-major order: index ``3 * (drow + 1) + (dcol + 1)``.
WINDOW_OFFSETS: tuple[tuple[int, int], ...] = tuple((dk, dl) for dk in (-1, 0, 1) for dl in (-1, 0, 1))


@functools.lru_cache(maxsize=16)
def window_offsets(device: torch.device) -> torch.Tensor:
    """``(9, 2)`` int64 :data:`WINDOW_OFFSETS` on ``device`` (built once per device)."""
    return torch.tensor(WINDOW_OFFSETS, dtype=torch.int64, device=device)


def dynamic_flow(
    screen: torch.Tensor,
    depth: torch.Tensor,
    config: torch.Tensor,
    landed: torch.Tensor,
    block: torch.Tensor,
    landing: torch.Tensor,
    target: torch.Tensor,
    zoom: int,
    camera: Camera,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The dynamic gradient flow at the loss level ``zoom`` (paper, eq. 19).

    A point whose landing block is active in the zoomed-out target is matched
    and gets nothing. Every other point that entered the level and landed on
    the grid is pulled, per axis, towards each active target block ``q !=
    landing`` of the 3x3 window around its input block:
    ``d|p - T_q|_1 / d(x, y) = sign(p - T_q)``. The sign is taken in screen
    coordinates, where it equals the sign in metres (at a fixed depth, x grows
    with the column and y with the row). Points landing off the grid get
    nothing: they have left the screen, as their counterparts in the target
    did, so even the true shift could not match them.

    All tensors on one device (any); the outputs live there too.

    Args:
        screen: ``(P, 2)`` float ``(row, col)`` projection ``P(p)`` of each point, screen pixels.
        depth: ``(P,)`` float depth ``z`` of each point, metres.
        config: ``(P,)`` int64 configuration of each point in ``[0, n)``.
        landed: ``(P,)`` bool, the point entered the level and its landing block is on the grid.
        block: ``(P, 2)`` int64 input block ``(row, col) >> zoom`` of each point.
        landing: ``(P, 2)`` int64 landing block (the nearest XY-adjustment); read only where ``landed``.
        target: ``(n, H / 2^zoom, W / 2^zoom)`` bool zoomed-out target.
        zoom: the loss level (blocks of ``2^zoom`` screen pixels).
        camera: camera and screen (metres per screen pixel for the loss).

    Returns:
        ``(flow, loss, matched)``: ``(P, 2)`` flow ``dJ/d(x, y)`` (dtype of ``screen``,
        dimensionless sums of signs), ``()`` loss ``J`` in metres (the summed L1 distance
        of the pulled points to the adjustments pulling them) and ``(P,)`` bool matched.
    """
    grid_h, grid_w = target.shape[1:]
    flat_target = target.reshape(-1)
    config_offset = config * (grid_h * grid_w)
    landing_cell = torch.where(landed, config_offset + landing[:, 0] * grid_w + landing[:, 1], 0)
    matched = landed & flat_target.take(landing_cell)
    flow = torch.zeros_like(screen)

    # Only the unmatched points are pulled; they are few once training is under way.
    pulled = (landed & ~matched).nonzero().squeeze(1)
    screen, block, landing = screen.index_select(0, pulled), block.index_select(0, pulled), landing.index_select(0, pulled)
    config_offset = config_offset.index_select(0, pulled)
    window = block[:, None, :] + window_offsets(block.device)  # (p, 9, 2) candidate blocks q
    in_grid = inside(window, grid_h, grid_w)
    window_cell = torch.where(in_grid, config_offset[:, None] + window[..., 0] * grid_w + window[..., 1], 0)
    is_landing = (window == landing[:, None, :]).all(-1)
    weight = (in_grid & flat_target.take(window_cell) & ~is_landing).to(screen.dtype)[..., None]  # (p, 9, 1)
    offset = screen[:, None, :] - (window + 0.5) * (1 << zoom)  # (p, 9, 2) screen pixels from q's centre
    flow.index_copy_(0, pulled, (torch.sign(offset) * weight).sum(1).flip(-1))  # (row, col) -> (x, y)
    metres_per_pixel = torch.stack(camera.metres_per_screen_pixel(depth.index_select(0, pulled)), dim=-1)  # (p, 2)
    loss = ((offset.abs() * weight).sum(1) * metres_per_pixel).sum()
    return flow, loss, matched

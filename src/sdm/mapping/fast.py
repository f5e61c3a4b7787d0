"""The point-based SDM chain: every active pixel is a row (pixel, point, depth).

Same output as the dense grid formulation in the large-``c`` limit (tests hold
the two together), at a fraction of the cost: the work is proportional to the
number of points, not to the screen area times the kernel size.

At level ``k`` (block size ``B = 2^k``), a point at pixel ``(r, c)`` has phase
``(r mod B, c mod B)`` and block ``(r div B, c div B)``. It lands in block
``clamp(floor(P(p) / B), block - 1, block + 1)`` (the nearest XY-adjustment of
its 3x3 kernel), moves to pixel ``landing * B + phase`` and competes by
``rmin`` with the points of the same phase that landed in the same block. A
point landing off the grid is dropped, as is every ``rmin`` loser, for all
later levels.

Rows are never compacted: dropped points stay in the arrays behind an
``alive`` mask and are routed to a sentinel cell, because boolean-mask
indexing costs more than the arithmetic it would save at these sizes.
"""
from __future__ import annotations

import torch

from ..camera import Camera
from ..representation import inside
from .result import MappingResult

_WINDOW = torch.tensor([(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)], dtype=torch.int64)  # (9, 2)
_NO_RANK = torch.iinfo(torch.int64).max


class _CellScratch:
    """A reusable ``int64`` buffer over all (configuration, pixel) cells, kept at ``_NO_RANK``.

    Filling an ``n * H * W`` buffer at every level would cost more than the rest
    of the level; instead only the touched cells are reset after use.
    """

    def __init__(self) -> None:
        self.buffer = torch.empty(0, dtype=torch.int64)

    def winners(self, cell: torch.Tensor, rank: torch.Tensor, n_cells: int) -> torch.Tensor:
        """``(p,)`` bool: the point of lowest rank in each cell (cell ``n_cells`` is a sentinel)."""
        if self.buffer.numel() < n_cells + 1:
            self.buffer = torch.full((n_cells + 1,), _NO_RANK, dtype=torch.int64)
        self.buffer.scatter_reduce_(0, cell, rank, reduce="amin")
        won = self.buffer.take(cell) == rank
        self.buffer.index_fill_(0, cell, _NO_RANK)
        return won


_SCRATCH = _CellScratch()


def fast_mapping(
    points: torch.Tensor,
    pixels: torch.Tensor,
    config: torch.Tensor,
    rank: torch.Tensor,
    target: torch.Tensor,
    steps: int,
    zoom: int,
    camera: Camera,
) -> MappingResult:
    """Run SDM levels ``steps, steps-1, ..., zoom`` on points; loss and flow at level ``zoom``.

    Args:
        points: ``(P, 3)`` float shifted points ``p`` in metres (detached, checked), ``z > 0``.
        pixels: ``(P, 2)`` int64 pixel each point sits in at the start (its pixel in ``I~``).
        config: ``(P,)`` int64 configuration index of each point in ``[0, n)``.
        rank: ``(P,)`` int64 ``rmin`` priority, distinct within a configuration; lower wins.
        target: ``(n, H / 2^zoom, W / 2^zoom)`` bool zoomed-out target at the loss level.
        steps: the coarsest level ``s``.
        zoom: the loss level, ``0 <= zoom <= steps``.
        camera: camera and screen ``(H, W)``.

    Returns:
        :class:`MappingResult`.
    """
    height, width = camera.screen_shape
    n_cells = int(target.shape[0]) * height * width
    screen = camera.project(points, validate=False)  # (P, 2) continuous (row, col)
    # floor(P(p) / 2^k) == floor(P(p)) >> k for every level k: one floor for the whole chain.
    projected_pixel = torch.floor(screen).long()
    alive = torch.ones(points.shape[0], dtype=torch.bool)
    current = pixels
    config_offset = config * (height * width)
    to_cell = torch.tensor([width, 1])
    for level in range(steps, zoom - 1, -1):
        block = current >> level
        # Landing block - input block, limited to the 3x3 kernel; the point keeps its phase,
        # so its new pixel is its old one moved by whole blocks.
        step = torch.clamp((projected_pixel >> level) - block, -1, 1)
        if level == zoom:
            entered, entered_block, entered_landing = alive, block, block + step
        current = current + (step << level)
        # The new pixel is on the screen exactly when its landing block is on the block grid.
        candidate = alive & inside(current, height, width)
        if level == zoom:
            landed = candidate
        cell = torch.where(candidate, config_offset + (current * to_cell).sum(1), n_cells)
        alive = candidate & _SCRATCH.winners(cell, rank, n_cells)

    out_pixels = torch.where(alive[:, None], current, -1)
    flow, loss, matched = _dynamic_flow(screen, points[:, 2], config, landed, entered_block, entered_landing, target,
                                        zoom, camera)
    return MappingResult(out_pixels, flow, loss, entered, matched, zoom, landed)


def _dynamic_flow(screen, depth, config, landed, block, landing, target, zoom, camera):
    """Dynamic gradient flow at the loss level (paper eq. 19; notes, section 5).

    A point whose landing block is active in the zoomed-out target is matched
    and gets nothing. Every other point that entered the level and landed on
    the grid is pulled, per axis, towards each active target block ``q !=
    landing`` of the 3x3 window around its input block:
    ``d|p - T_q|_1 / d(x, y) = sign(p - T_q)``. The sign is taken in screen
    coordinates, where it equals the sign in metres (at a fixed depth, x grows
    with the column and y with the row). Points landing off the grid get
    nothing: they have left the screen, as their counterparts in the target
    did, so even the true shift could not match them.
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
    window = block[:, None, :] + _WINDOW  # (p, 9, 2) candidate blocks q
    in_grid = inside(window, grid_h, grid_w)
    window_cell = torch.where(in_grid, config_offset[:, None] + window[..., 0] * grid_w + window[..., 1], 0)
    is_landing = (window == landing[:, None, :]).all(-1)
    weight = (in_grid & flat_target.take(window_cell) & ~is_landing).to(screen.dtype)[..., None]  # (p, 9, 1)
    offset = screen[:, None, :] - (window + 0.5) * (1 << zoom)  # (p, 9, 2) screen pixels from q's centre
    flow.index_copy_(0, pulled, (torch.sign(offset) * weight).sum(1).flip(-1))  # (row, col) -> (x, y)
    metres_per_pixel = torch.stack(camera.metres_per_screen_pixel(depth.index_select(0, pulled)), dim=-1)  # (p, 2) (row, col)
    loss = ((offset.abs() * weight).sum(1) * metres_per_pixel).sum()
    return flow, loss, matched

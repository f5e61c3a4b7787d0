"""The point-based SDM chain: every active pixel is a row (pixel, point, depth).

Same output as the dense grid formulation in the large-``c`` limit (tests hold
the two together), at a fraction of the cost: the work is proportional to the
number of points, not to the screen area times the kernel size.

At zoom ``k`` (block size ``B = 2^k``), a point at pixel ``(r, c)`` has phase
``(r mod B, c mod B)`` and block ``(r div B, c div B)``. It lands in block
``clamp(floor(P(p) / B), block - 1, block + 1)`` (the nearest XY-adjustment of
its 3x3 kernel), moves to pixel ``landing * B + phase`` and competes by
``rmin`` with the points of the same phase that landed in the same block. A
point landing off the grid is dropped, as is every ``rmin`` loser, for all
later zooms.

Rows are never compacted: dropped points stay in the arrays behind an
``alive`` mask and are routed to a sentinel cell, because boolean-mask
indexing costs more than the arithmetic it would save at these sizes.
"""
from __future__ import annotations

import torch

from ..camera import Camera
from ..representation import NO_RANK, inside
from . import native as native_kernel
from .flow import dynamic_flow, pull_loss
from .result import MappingResult


class _CellScratch:
    """Reusable ``int64`` buffers over all (configuration, pixel) cells, kept at ``NO_RANK``, one per device.

    Filling an ``n * H * W`` buffer at every zoom would cost more than the rest
    of the zoom; instead only the touched cells are reset after use.
    """

    def __init__(self) -> None:
        self.buffers: dict[torch.device, torch.Tensor] = {}

    def buffer(self, device: torch.device, n_cells: int) -> torch.Tensor:
        """``(>= n_cells + 1,)`` int64 on ``device``, every entry ``NO_RANK``."""
        buffer = self.buffers.get(device)
        if buffer is None or buffer.numel() < n_cells + 1:
            buffer = self.buffers[device] = torch.full((n_cells + 1,), NO_RANK, dtype=torch.int64, device=device)
        return buffer

    def winners(self, cell: torch.Tensor, rank: torch.Tensor, n_cells: int) -> torch.Tensor:
        """``(p,)`` bool: the point of lowest rank in each cell (cell ``n_cells`` is a sentinel).

        ``cell`` and ``rank`` are ``(p,)`` int64 on one device; the buffer used lives there.
        """
        buffer = self.buffer(cell.device, n_cells)
        buffer.scatter_reduce_(0, cell, rank, reduce="amin")
        won = buffer.take(cell) == rank
        buffer.index_fill_(0, cell, NO_RANK)
        return won


_SCRATCH = _CellScratch()


def fast_mapping(
    points: torch.Tensor,
    pixels: torch.Tensor,
    config: torch.Tensor,
    rank: torch.Tensor,
    target: torch.Tensor,
    s: int,
    zoom: int,
    camera: Camera,
    flow_rule=dynamic_flow,
    native: bool | None = None,
) -> MappingResult:
    """Run the SDM zooms ``s, s-1, ..., zoom`` on points; loss and flow at zoom ``zoom``.

    Args:
        points: ``(P, 3)`` float shifted points ``p`` in metres (detached, checked), ``z > 0``.
            Every tensor argument lives on the device of ``points`` (any device); so do the results.
        pixels: ``(P, 2)`` int64 pixel each point sits in at the start (its pixel in ``I~``).
        config: ``(P,)`` int64 configuration index of each point in ``[0, n)``.
        rank: ``(P,)`` int64 ``rmin`` priority, distinct within a configuration; lower wins.
        target: ``(n, H / 2^zoom, W / 2^zoom)`` bool zoomed-out target at the loss zoom.
        s: the coarsest zoom.
        zoom: the loss zoom (the finest), ``0 <= zoom <= s``.
        camera: camera and screen ``(H, W)``.
        flow_rule: the gradient rule (default the paper's :func:`~sdm.mapping.flow.dynamic_flow`;
            the flows of the rules in :data:`sdm.RULES`), called with the same arguments.
        native: run the zoom loop (and the paper's flow) in the compiled CPU kernel of
            :mod:`~sdm.mapping.native`: ``None`` (default) wherever it can (contiguous CPU
            tensors, the kernel built), ``False`` never (the torch path; same results, bit for bit).

    Returns:
        :class:`MappingResult`.
    """
    height, width = camera.screen_shape
    n_cells = int(target.shape[0]) * height * width
    screen = camera.project(points, validate=False)  # (P, 2) continuous (row, col)
    # floor(P(p) / 2^k) == floor(P(p)) >> k for every zoom k: one floor for the whole chain.
    projected_pixel = torch.floor(screen).long()
    if native is not False and native_kernel.serves(projected_pixel, pixels, config, rank, target):
        scratch = _SCRATCH.buffer(points.device, 2 * n_cells + 1)  # the kernel's two rmin tables
        out_pixels, entered, landed, block, landing = native_kernel.chain(
            projected_pixel, pixels, config, rank, scratch, height, width, s, zoom)
        if flow_rule is dynamic_flow and screen.dtype == torch.float64:
            flow, matched, pulled, window_l1 = native_kernel.paper_flow(screen, config, landed, block, landing,
                                                                        target, zoom)
            loss = pull_loss(window_l1, points[:, 2].index_select(0, pulled), camera)
        else:
            flow, loss, matched = flow_rule(screen, points[:, 2], config, landed, block, landing, target, zoom,
                                            camera)
        return MappingResult(out_pixels, flow, loss, entered, matched, zoom, landed)
    alive = torch.ones(points.shape[0], dtype=torch.bool, device=points.device)
    current = pixels
    config_offset = config * (height * width)
    for at in range(s, zoom - 1, -1):  # each zoom, coarsest first
        block = current >> at
        # Landing block - input block, limited to the 3x3 kernel; the point keeps its phase,
        # so its new pixel is its old one moved by whole blocks.
        step = torch.clamp((projected_pixel >> at) - block, -1, 1)
        if at == zoom:
            entered, entered_block, entered_landing = alive, block, block + step
        current = current + (step << at)
        # The new pixel is on the screen exactly when its landing block is on the block grid.
        candidate = alive & inside(current, height, width)
        if at == zoom:
            landed = candidate
        cell = torch.where(candidate, config_offset + current[:, 0] * width + current[:, 1], n_cells)
        alive = candidate & _SCRATCH.winners(cell, rank, n_cells)

    out_pixels = torch.where(alive[:, None], current, -1)
    flow, loss, matched = flow_rule(screen, points[:, 2], config, landed, entered_block, entered_landing, target,
                                       zoom, camera)
    return MappingResult(out_pixels, flow, loss, entered, matched, zoom, landed)


"""The dynamic gradient flow (paper, eq. 19): one rule, used by every SDM path.

Both implementations of the layer (:mod:`~sdm.mapping.fast` and the dense grid
reference :mod:`~sdm.mapping.dense`) and the single-point explainer
(:func:`~sdm.mapping.explain.explain_point`) decide *where* each point lands;
what the backward pass does with that is decided here, once (docs/method/paper.md,
"Backward pass").
"""
from __future__ import annotations

import functools
from typing import NamedTuple

import torch

from ..camera import Camera

#: The 3x3 kernel window, ``(drow, dcol)`` in row-major order: index ``3 * (drow + 1) + (dcol + 1)``.
WINDOW_OFFSETS: tuple[tuple[int, int], ...] = tuple((dk, dl) for dk in (-1, 0, 1) for dl in (-1, 0, 1))


def _constant(build):
    """``build(*args)`` (a small constant tensor for a device, dtype, ...), cached per arguments.

    Under ``torch.compile`` it is built afresh instead: Dynamo traces through an ``lru_cache`` (and warns
    that it does), and a constant built inside the graph is folded into it anyway.
    """
    cached = functools.lru_cache(maxsize=64)(build)

    @functools.wraps(build)
    def constant(*args):
        return build(*args) if torch.compiler.is_compiling() else cached(*args)

    return constant


@_constant
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
    """The dynamic gradient flow at the loss zoom ``zoom`` (paper, eq. 19).

    A point whose landing block is active in the zoomed-out target is matched
    and gets nothing. Every other point that entered the loss zoom and landed on
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
        landed: ``(P,)`` bool, the point entered the loss zoom and its landing block is on the grid.
        block: ``(P, 2)`` int64 input block ``(row, col) >> zoom`` of each point.
        landing: ``(P, 2)`` int64 landing block (the nearest XY-adjustment); read only where ``landed``.
        target: ``(n, H / 2^zoom, W / 2^zoom)`` bool zoomed-out target.
        zoom: the loss zoom (blocks of ``2^zoom`` screen pixels).
        camera: camera and screen (metres per screen pixel for the loss).

    Returns:
        ``(flow, loss, matched)``: ``(P, 2)`` flow ``dJ/d(x, y)`` (dtype of ``screen``,
        dimensionless sums of signs), ``()`` loss ``J`` in metres (the summed L1 distance
        of the pulled points to the adjustments pulling them) and ``(P,)`` bool matched.
    """
    matched = landing_matched(config, landed, landing, target)
    flow = torch.zeros_like(screen)

    # Only the unmatched points are pulled; they are few once training is under way.
    pulled = (landed & ~matched).nonzero().squeeze(1)
    screen, depth = screen.index_select(0, pulled), depth.index_select(0, pulled)
    block = block.index_select(0, pulled)
    window = block_window(block, config.index_select(0, pulled), target, zoom, screen.dtype)
    offset = window.offset(screen)  # (p, 2, 3) screen pixels
    weight = window.pulling(landing.index_select(0, pulled)).to(screen.dtype)  # (p, 9) 1.0 where block q pulls
    grid = weight.view(-1, 3, 3)  # (p, dk, dl)
    per_row = grid[:, :, 0] + grid[:, :, 1] + grid[:, :, 2]  # (p, 3) pulling blocks in window row dk
    per_col = grid[:, 0, :] + grid[:, 1, :] + grid[:, 2, :]  # (p, 3) pulling blocks in window column dl
    sign = torch.sign(offset)  # (p, 2, 3)
    pull = torch.stack((_dot3(sign[:, 0], per_row), _dot3(sign[:, 1], per_col)), dim=-1)  # (p, 2) (row, col)
    flow.index_copy_(0, pulled, pull.flip(-1))  # (row, col) -> (x, y)
    loss = pull_loss(_window_l1(offset.abs(), grid), depth, camera)
    return flow, loss, matched


def landing_matched(config: torch.Tensor, landed: torch.Tensor, landing: torch.Tensor,
                    target: torch.Tensor) -> torch.Tensor:
    """``(P,)`` bool: the point landed on the grid in a block active in ``target`` (it gets no pull).

    Args:
        config: ``(P,)`` int64 configuration of each point in ``[0, n)``.
        landed: ``(P,)`` bool, the landing block is on the grid (``landing`` is read only there).
        landing: ``(P, 2)`` int64 landing block ``(row, col)``.
        target: ``(n, h, w)`` bool target at the zoom of ``landing``; all on one device.
    """
    grid_h, grid_w = target.shape[1:]
    landing_cell = torch.where(landed, config * (grid_h * grid_w) + landing[:, 0] * grid_w + landing[:, 1], 0)
    return landed & target.reshape(-1).take(landing_cell)


class Window(NamedTuple):
    """The 3x3 window of blocks around one centre block per point, at one zoom (:func:`block_window`).

    Window block ``q = centre + (dk, dl)`` has index ``3 * (dk + 1) + (dl + 1)`` (row-major,
    :data:`WINDOW_OFFSETS`). Its centre is ``(centre + (dk, dl) + 0.5) * 2^zoom`` screen pixels,
    so a row of the window shares its centre row and a column its centre column: ``centres``
    holds three values per axis instead of nine (the separable form; :func:`nine` expands it).
    All tensors on the device of the centre blocks.
    """

    #: ``(p, 2)`` int64 centre block ``(row, col)`` of each point's window.
    centre: torch.Tensor
    #: ``(p, 2, 3)`` float, screen pixels: ``[:, 0, dk + 1]`` the centre row of window row ``dk``,
    #: ``[:, 1, dl + 1]`` the centre column of window column ``dl``.
    centres: torch.Tensor
    #: ``(p, 9)`` bool, the window block is on the block grid.
    on_grid: torch.Tensor
    #: ``(p, 9)`` int64 index of the window block in ``target.reshape(-1)`` (0 off the grid).
    cell: torch.Tensor
    #: ``(p, 9)`` bool, the window block is on the grid and active in the target.
    active: torch.Tensor

    def offset(self, screen: torch.Tensor) -> torch.Tensor:
        """``(p, 2, 3)`` ``p - T_q`` per axis and shift: ``screen`` ``(p, 2)`` ``(row, col)`` minus :attr:`centres`."""
        return screen[:, :, None] - self.centres

    def pulling(self, landing: torch.Tensor) -> torch.Tensor:
        """``(p, 9)`` bool, the paper's pulling blocks: :attr:`active` and not the landing block.

        ``landing`` ``(p, 2)`` int64 must lie in the window (it does: the kernel moves a point
        by at most one block, and a window centred on the landing block holds it at index 4).
        """
        step = landing - self.centre  # (p, 2) in {-1, 0, 1}
        landing_index = step[:, 0] * 3 + step[:, 1] + 4  # (p,) window index of the landing block, 0..8
        return self.active & (_window_index(self.centre.device) != landing_index[:, None])

    def blocks(self) -> torch.Tensor:
        """``(p, 9, 2)`` int64 the window blocks ``(row, col)``."""
        return self.centre[:, None, :] + window_offsets(self.centre.device)


def block_window(centre: torch.Tensor, config: torch.Tensor, target: torch.Tensor, zoom: int,
                 dtype: torch.dtype) -> Window:
    """The 3x3 :class:`Window` around block ``centre`` of each point: the one window of every gradient rule.

    Args:
        centre: ``(p, 2)`` int64 centre block ``(row, col)`` at zoom ``zoom`` (the input block for
            eq. 19, the landing block for the centred rules).
        config: ``(p,)`` int64 configuration of each point in ``[0, n)``.
        target: ``(n, h, w)`` bool blocks that may pull (the zoomed-out target, or a rule's version of it).
        zoom: the zoom (blocks of ``2^zoom`` screen pixels).
        dtype: float dtype of the centres (that of the screen coordinates they are compared with).

    All tensors on one device (any); the window lives there too. The centres are exact: block
    indices are small integers, so ``(block + shift + 0.5) * 2^zoom`` rounds nowhere.
    """
    grid_h, grid_w = target.shape[1:]
    device = centre.device
    shifted = centre[:, :, None] + _axis_shifts(device, torch.int64)  # (p, 2, 3) blocks per axis
    centres = (centre[:, :, None] + _axis_shifts(device, dtype) + 0.5) * (1 << zoom)  # (p, 2, 3) screen pixels
    row_ok, col_ok = _on_axis(shifted[:, 0], grid_h), _on_axis(shifted[:, 1], grid_w)  # (p, 3) each
    on_grid = (row_ok[:, :, None] & col_ok[:, None, :]).reshape(-1, 9)
    base_cell = config * (grid_h * grid_w) + centre[:, 0] * grid_w + centre[:, 1]
    cell = torch.where(on_grid, base_cell[:, None] + _window_deltas(grid_w, device), 0)  # (p, 9)
    active = on_grid & target.reshape(-1).take(cell)
    return Window(centre, centres, on_grid, cell, active)


def nine(per_axis: torch.Tensor) -> torch.Tensor:
    """``(p, 9, 2)`` ``(row, col)`` per window block from a separable ``(p, 2, 3)`` (``Window.centres``, ``offset``).

    Block ``3 * (dk + 1) + (dl + 1)`` takes row value ``[:, 0, dk + 1]`` and column value
    ``[:, 1, dl + 1]``: the same floats, copied (a contiguous tensor).
    """
    rows = per_axis[:, 0, :, None].expand(-1, 3, 3)
    cols = per_axis[:, 1, None, :].expand(-1, 3, 3)
    return torch.stack((rows, cols), dim=-1).reshape(-1, 9, 2)


def pull_loss(window_l1: torch.Tensor, depth: torch.Tensor, camera: Camera) -> torch.Tensor:
    """``()`` the loss ``J`` in metres from the pulled points' summed window distances.

    Args:
        window_l1: ``(p, 2)`` per pulled point and axis ``(row, col)``, the summed ``|p - T_q|``
            over the blocks pulling it, screen pixels.
        depth: ``(p,)`` depth of each pulled point, metres.
        camera: metres per screen pixel at that depth.

    The one place the loss is formed: the paper's rule on the torch path and in the compiled
    kernel (:mod:`~sdm.mapping.native`), so both give the same float, and the other rules.
    """
    metres_per_pixel = torch.stack(camera.metres_per_screen_pixel(depth), dim=-1)  # (p, 2) (row, col)
    return (window_l1 * metres_per_pixel).sum()


def _on_axis(index: torch.Tensor, size: int) -> torch.Tensor:
    """``(...)`` bool: integer ``index`` in ``[0, size)``."""
    return (index >= 0) & (index < size)


def _window_l1(distance: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """``(p, 2)``: per axis, the sum over the window's pulling blocks ``q`` (row-major) of ``|p - T_q|``.

    Args:
        distance: ``(p, 2, 3)`` ``|offset|`` per axis and shift ``-1, 0, 1``.
        weight: ``(p, 3, 3)`` 1.0 where block ``(dk, dl)`` pulls, else 0.0.

    The terms are added one at a time in the window's row-major order, so the
    value is the same float as summing the nine ``(p, 9, 2)`` products of the
    grid formulation (adding an exact zero for blocks that do not pull).
    """
    total = torch.zeros_like(distance[:, :, 0])
    for dk in range(3):
        for dl in range(3):
            terms = torch.stack((distance[:, 0, dk], distance[:, 1, dl]), dim=-1)  # (p, 2)
            total = total + terms * weight[:, dk, dl, None]
    return total


def _dot3(values: torch.Tensor, counts: torch.Tensor) -> torch.Tensor:
    """``(p,)``: ``sum_i values[:, i] * counts[:, i]`` over three columns (integers here: exact in any order)."""
    return values[:, 0] * counts[:, 0] + values[:, 1] * counts[:, 1] + values[:, 2] * counts[:, 2]


@_constant
def _axis_shifts(device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    """``(3,)`` ``-1, 0, 1`` in ``dtype`` on ``device``."""
    return torch.tensor([-1, 0, 1], dtype=dtype, device=device)


@_constant
def _window_deltas(grid_width: int, device: torch.device) -> torch.Tensor:
    """``(9,)`` int64 flat-cell offset ``dk * grid_width + dl`` of each window block."""
    return torch.tensor([dk * grid_width + dl for dk, dl in WINDOW_OFFSETS], dtype=torch.int64, device=device)


@_constant
def _window_index(device: torch.device) -> torch.Tensor:
    """``(9,)`` int64 ``0..8``."""
    return torch.arange(9, dtype=torch.int64, device=device)

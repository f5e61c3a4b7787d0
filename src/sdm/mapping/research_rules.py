"""Experimental gradient rules: the experiments of docs/method.md, "Beyond the paper"; no table uses them.

Issue 12 asked for a rule that is unbiased under noise: with noisy targets the
paper's summed flow does not vanish at the true shift theta*, so SGD settles
beyond it. The rules here change *which* points are pulled and *how much*, each
keeping theta* an exact fixed point without noise (no point is unmatched there,
so no rule pulls anything). They were measured (docs/method.md, its tables of
Table 2 per rule and of the flow at theta*); the one that met the bar,
``closed_centred_r1``, is in :data:`sdm.FLOW_RULES` with the paper's rule, and no
configuration or table of the workflow uses the ones below.

Selecting one: by name wherever a rule is named (``TrainSettings(flow="closed")``,
``SpatialDomainMapping(flow="closed")``, ``research.rules.names`` of the workflow,
``benchmarks/flow_rules.py --rules``: :func:`sdm.mapping.rules.flow_rule` looks in
:data:`sdm.FLOW_RULES` first, then in :data:`RESEARCH_RULES`), or as the function
itself (``SpatialDomainMapping(flow=RESEARCH_RULES["nearest"])``).

Shapes and signature: those of :mod:`sdm.mapping.rules`.
"""
from __future__ import annotations

import torch

from ..camera import Camera
from .flow import block_window, dynamic_flow, landing_matched, nine
from .rules import FlowRule, by_zoom, closing, sign_flow, window_rule


def _uncovered_window(screen, config, landed, landing, target, zoom, camera):
    """The reverse (Chamfer-like) side: target blocks that no point's projection covers, around each landed point.

    A block is *covered* when the projection of some point (alive or not, landed
    or not) falls in it: at theta* without noise the zoomed target is exactly the
    set of covered blocks (the target is the occupancy of the moved points), so
    nothing is uncovered there and theta* stays an exact fixed point.

    Returns:
        ``(pulled, offset, weight)``: ``pulled`` ``(p,)`` int64 indices of the landed points;
        ``offset`` ``(p, 9, 2)`` screen pixels from each block of the 3x3 window around the
        point's landing block to the point; ``weight`` ``(p, 9)`` bool, the block is on the
        grid, uncovered and active in ``target``, and not the landing block.
    """
    grid_h, grid_w = target.shape[1:]
    height, width = camera.screen_shape
    projected = torch.floor(screen).long()
    on_screen = (projected[:, 0] >= 0) & (projected[:, 0] < height) & (projected[:, 1] >= 0) & (projected[:, 1] < width)
    config_offset = config * (grid_h * grid_w)
    covered = torch.zeros(target.numel(), dtype=torch.bool, device=target.device)
    projected_block = projected >> zoom
    covered_cell = (config_offset + projected_block[:, 0] * grid_w + projected_block[:, 1])[on_screen]
    covered[covered_cell] = True
    uncovered = target & ~covered.view(target.shape)
    pulled = landed.nonzero().squeeze(1)
    centre = landing.index_select(0, pulled)
    window = block_window(centre, config.index_select(0, pulled), uncovered, zoom, screen.dtype)
    offset = nine(window.offset(screen.index_select(0, pulled)))
    return pulled, offset, window.pulling(centre)  # the window is centred on the landing block


def _reached(screen, landing, zoom):
    """``(P,)`` bool: the point's landing block is the block its projection falls in (the kernel did not clamp it).

    A point that the 3x3 kernel stopped short of its projection is still on its
    way; its window does not contain where it is going, so its pull says little
    about the shift and, under noise, drags towards the target's spread-out edge.
    """
    return ((torch.floor(screen).long() >> zoom) == landing).all(1)


def _two_sided(prepare=None, reverse_prepare=None) -> FlowRule:
    """The one-sided rule on ``prepare(target)`` plus the reverse pull of uncovered blocks of the target.

    The forward side is :func:`~sdm.mapping.rules.window_rule` ``(prepare=prepare)``:
    unmatched points are pulled towards the active blocks of their window. The reverse
    side pulls every landed point towards the blocks of the 3x3 window around its
    landing block that are active in the target but covered by no point's projection
    (a Chamfer loss's second direction), by the same ``sign(p - T_q)``. A closing must
    not be used on the reverse side (``reverse_prepare``) unless it adds no block
    without noise: the blocks it adds would be uncovered at theta*.
    """
    forward = window_rule(prepare=prepare)

    def rule(screen, depth, config, landed, block, landing, target, zoom, camera: Camera):
        flow, loss, matched = forward(screen, depth, config, landed, block, landing, target, zoom, camera)
        reverse_target = reverse_prepare(target, zoom) if reverse_prepare is not None else target
        pulled, offset, weight = _uncovered_window(screen, config, landed, landing, reverse_target, zoom, camera)
        reverse_flow, reverse_loss = sign_flow(screen, depth, pulled, offset, weight.to(screen.dtype), camera)
        return flow + reverse_flow, loss + reverse_loss, matched

    return rule


def _nearest(offset, weight):
    """One-hot weight on the pulling block nearest (L1, screen pixels) to the point; ties: first in row-major order."""
    distance = torch.where(weight, offset.abs().sum(-1), torch.inf)  # (p, 9)
    nearest = distance.argmin(1, keepdim=True)
    return torch.zeros_like(distance).scatter_(1, nearest, 1.0) * weight.to(distance.dtype)


def _normalised(offset, weight):
    """Each point's pulls divided by their number: the mean sign, at most 1 per axis."""
    weights = weight.to(offset.dtype)
    return weights / weights.sum(1, keepdim=True).clamp(min=1.0)


def _closing_pixels(radius: int, at_least: int = 0):
    """Closing with a square of ``radius`` *screen pixels*: ``2 (radius >> zoom) + 1`` blocks at level ``zoom``.

    Noise moves a pixel by at most ``level`` screen pixels, so it opens holes of
    that size at full resolution; zooming out already fills them once a block is
    wider than the noise. A closing of a fixed number of *blocks* (``closed5``)
    over-fills the coarse levels (5 blocks of 16 pixels bridge whole gaps between
    cars, every point is matched, theta hardly moves until the fine levels, where
    the 3x3 kernel can no longer reach). Measured in docs/method.md. ``at_least``
    blocks of radius are closed at every level (``closed_m2``: 1, i.e. 3x3 at the
    coarse levels, as ``closed``).
    """
    closings = {}

    def close(target, zoom):
        blocks = max(radius >> zoom, at_least)
        if blocks == 0:
            return target
        if blocks not in closings:
            closings[blocks] = closing(2 * blocks + 1)
        return closings[blocks](target, zoom)

    return close


#: The four one-block moves along the flow's axes: ``(drow, dcol)`` for y+, y-, x+, x-.
_MOVES = ((1, 0), (-1, 0), (0, 1), (0, -1))


def _mismatch_descent(screen, depth, config, landed, block, landing, target, zoom, camera: Camera):
    """Per point, the discrete derivative of the exact block mismatch (false positives plus false negatives).

    The objective is CMA-ES's (:mod:`sdm.baselines.cmaes`) at level ``zoom``: the blocks of the points'
    *projections* ``floor(screen / 2^zoom)`` (every point, not only the chain's survivors: the chain drops
    ``rmin`` losers, whose holes would pull at theta*), against ``target``. For each point and each of the
    four one-block moves ``e`` it counts what that move alone would change:

    - leaving its block ``L``: ``-s(L)`` if the point is the block's only one, else 0;
    - arriving in ``L + e``: ``s(L + e)`` if no point is there, else 0;

    with ``s = +1`` for a block of the grid the target leaves empty (a false positive appears or goes),
    ``-1`` for an active one (a false negative) and ``0`` off the grid (nothing is counted there; points up
    to one block off the grid are included, so that their way back in is counted). Only moves that lower
    the count pull: the flow on an axis is ``(relu(-D(-e)) - relu(-D(+e))) / 2``, divided by the number of
    points sharing the block (so a block's pull does not grow with its points). Without noise the count is 0
    at theta*, no move lowers it, and theta* is an exact fixed point; nothing depends on the landing, so
    the forward (the chain) is unchanged and only the backward differs.

    Returns ``(flow, loss, matched)`` as :func:`~sdm.mapping.flow.dynamic_flow`, except that ``loss`` is
    the mismatch count itself (blocks, summed over the batch), not metres.
    """
    n, grid_h, grid_w = target.shape
    blocks = torch.floor(screen / float(1 << zoom)).long()  # (P, 2) exact: 2^zoom is a power of two
    near = (blocks[:, 0] >= -1) & (blocks[:, 0] <= grid_h) & (blocks[:, 1] >= -1) & (blocks[:, 1] <= grid_w)
    moved = near.nonzero().squeeze(1)
    block_of = blocks.index_select(0, moved)  # (p, 2)
    base = config.index_select(0, moved) * (grid_h * grid_w)  # (p,) first cell of the point's configuration
    flat_target = target.reshape(-1)

    def cell_at(rows, cols):
        """(p,) cell index of blocks ``(rows, cols)`` (0 off the grid) and (p,) bool on the grid."""
        on_grid = (rows >= 0) & (rows < grid_h) & (cols >= 0) & (cols < grid_w)
        return torch.where(on_grid, base + rows * grid_w + cols, 0), on_grid

    own_cell, own_on_grid = cell_at(block_of[:, 0], block_of[:, 1])
    count = torch.bincount(own_cell[own_on_grid], minlength=flat_target.numel())  # points per grid block

    def cost(cell, on_grid):
        """(p,) ``s``: +1 an empty grid block, -1 an active one, 0 off the grid."""
        return torch.where(flat_target.take(cell), -1.0, 1.0).to(screen.dtype) * on_grid

    own_count = torch.where(own_on_grid, count.take(own_cell), 1)
    leave = -cost(own_cell, own_on_grid) * (own_count == 1)
    change = []
    for drow, dcol in _MOVES:
        cell, on_grid = cell_at(block_of[:, 0] + drow, block_of[:, 1] + dcol)
        change.append(leave + cost(cell, on_grid) * (count.take(cell) == 0))
    down = torch.relu(-torch.stack(change, dim=-1))  # (p, 4) how much each move lowers the count
    pull = torch.stack((down[:, 3] - down[:, 2], down[:, 1] - down[:, 0]), dim=-1) / 2  # (p, 2) (x, y)
    flow = torch.zeros_like(screen)
    flow.index_copy_(0, moved, pull / own_count.to(screen.dtype)[:, None])
    covered = torch.zeros_like(flat_target)
    covered[own_cell[own_on_grid]] = True
    loss = (covered ^ flat_target).sum().to(screen.dtype)
    return flow, loss, landing_matched(config, landed, landing, target)


#: The experimental rules by name (docs/method.md, "Beyond the paper"); none is used by a table.
RESEARCH_RULES: dict[str, FlowRule] = {
    "nearest": window_rule(weigh=_nearest),
    "normalised": window_rule(weigh=_normalised),
    "reached": window_rule(select=_reached),
    "closed": window_rule(prepare=closing(3)),
    "closed5": window_rule(prepare=closing(5)),
    "closed7": window_rule(prepare=closing(7)),
    "closed_r2": window_rule(prepare=_closing_pixels(2)),
    "closed_r3": window_rule(prepare=_closing_pixels(3)),
    "closed_r4": window_rule(prepare=_closing_pixels(4)),
    "closed_m2": window_rule(prepare=_closing_pixels(2, at_least=1)),
    "centred": window_rule(centred=True),
    "closed_centred": window_rule(prepare=closing(3), centred=True),
    # 3x3 closing at zoom 0 only (radius 1 screen pixel), eq. 19 at the coarser levels.
    "closed_r1": window_rule(prepare=_closing_pixels(1)),
    # Chamfer-like: also pulled towards target blocks that no point's projection covers.
    "two_sided": _two_sided(),
    "closed_two_sided": _two_sided(prepare=closing(3)),
    # Issue 20: the discrete derivative of CMA-ES's objective at zoom 0, eq. 19 at the coarser levels.
    "mismatch_descent": by_zoom(_mismatch_descent, dynamic_flow, finest_coarse=1),
}

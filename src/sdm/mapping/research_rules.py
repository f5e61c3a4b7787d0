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


#: The four one-pixel moves: ``(drow, dcol)`` for y+, y-, x+, x-.
_MOVES = ((1, 0), (-1, 0), (0, 1), (0, -1))

#: ``group_crossing``'s kernel half-width in metres of theta (docs/method.md, "A rule aimed at the floor").
CROSSING_WIDTH = 2e-3
#: ``group_crossing``'s flow scale (a power of two: the scaled flow stays a multiple of ``1 / CROSSING_STEPS``).
CROSSING_SCALE = 8.0
#: The kernel is quantised to multiples of ``1 / CROSSING_STEPS``: every flow value is then an exact binary
#: fraction, so its sum over points is the same in any order (float64).
CROSSING_STEPS = 4096
#: ``group_crossing`` is eq. 19 at the levels ``>=`` this one (its crossing flow reads zoom 0's pixels).
CROSSING_FINEST_COARSE = 1


def rigid_groups(screen: torch.Tensor, depth: torch.Tensor, config: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The rigid groups of a batch: the points of one configuration with one depth.

    A point of ``Q`` is the back-projection of its pixel's centre at its depth, so a shift ``(a, b)`` moves it
    by ``f' a / z`` screen pixels: the points of one configuration at one depth move by the same whole number
    of pixels (a disc of ``E'`` and every disc at its depth), and no two of them ever share a pixel.

    Args:
        screen: ``(P, 2)`` float ``(row, col)`` screen pixels; depth: ``(P,)`` metres; config: ``(P,)`` int64.

    Returns:
        ``group`` ``(P,)`` int64 in ``[0, G)``, groups ordered by configuration then depth; ``first`` ``(G,)`` int64
        the smallest point index of each group. On the device of ``screen``.
    """
    depth_id = torch.unique(depth, return_inverse=True)[1]
    group = torch.unique(config * (int(depth_id.max()) + 1) + depth_id, return_inverse=True)[1]
    n_groups = int(group.max()) + 1
    first = torch.full((n_groups,), screen.shape[0], dtype=torch.int64, device=screen.device)
    first.scatter_reduce_(0, group, torch.arange(screen.shape[0], device=screen.device), "amin")
    return group, first


def group_move_changes(screen, group, config, target) -> torch.Tensor:
    """``(G, 4)`` how the exact zoom-0 pixel mismatch changes when one rigid group alone moves one pixel.

    The mismatch of a configuration is CMA-ES's objective (:mod:`sdm.baselines.cmaes`): the pixels covered by
    the projections ``floor(screen)`` of its points (all of them, not only the chain's survivors) against its
    target, false positives plus false negatives; off-screen pixels count nothing. For each group and each move
    of :data:`_MOVES` (y+, y-, x+, x-), with every other point where it is: a pixel the group leaves (one of
    its pixels that no other point covers and that the moved group does not cover again) adds 1 if the target
    holds it and removes 1 if not; a pixel it arrives in (not its own, covered by no other point) removes 1 if
    the target holds it, adds 1 if not.

    Args:
        screen: ``(P, 2)`` float ``(row, col)``; group: ``(P,)`` int64 (:func:`rigid_groups`); config: ``(P,)``
            int64; target: ``(n, H, W)`` bool, zoom 0.

    Returns:
        ``(changes, mismatch)``: ``changes`` ``(G, 4)`` float (dtype of ``screen``), exact integers;
        ``mismatch`` ``()`` the count itself before any move, summed over the configurations (same dtype).
        On the device of ``screen``.
    """
    n, height, width = target.shape
    pixel = torch.floor(screen).long()
    margin = 2  # a group's pixels up to a pixel off the screen can come back in with one move
    near = ((pixel[:, 0] >= -margin) & (pixel[:, 0] < height + margin)
            & (pixel[:, 1] >= -margin) & (pixel[:, 1] < width + margin))
    span = (height + 2 * margin + 2, width + 2 * margin + 2)

    def code(rows, cols):
        return (group * span[0] + (rows + margin + 1)) * span[1] + (cols + margin + 1)

    codes = torch.sort(code(pixel[:, 0], pixel[:, 1])[near]).values  # (p,) every near point's (group, pixel)

    def in_group(rows, cols):
        """``(P,)`` bool: a point of the same group covers pixel ``(rows, cols)``."""
        inside = (rows >= -margin - 1) & (rows <= height + margin) & (cols >= -margin - 1) & (cols <= width + margin)
        query = code(rows, cols)
        found = torch.searchsorted(codes, query).clamp(max=max(codes.numel() - 1, 0))
        return inside & (codes.numel() > 0) & (codes.take(found) == query)

    flat_target = target.reshape(-1)

    def pixel_at(rows, cols):
        """``(P,)`` cell index (0 off the screen), ``(P,)`` on the screen, ``(P,)`` target holds it."""
        on_screen = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
        cell = torch.where(on_screen, config * (height * width) + rows * width + cols, 0)
        return cell, on_screen, flat_target.take(cell) & on_screen

    own, own_on_screen, own_target = pixel_at(pixel[:, 0], pixel[:, 1])
    covering = torch.bincount(own[own_on_screen], minlength=flat_target.numel())  # points per pixel
    alone = own_on_screen & (covering.take(own) == 1)
    # +1 / -1 as integers in the float dtype: exact
    leave_change = torch.where(own_target, 1.0, -1.0).to(screen.dtype)
    changes = torch.zeros(int(group.max()) + 1 if group.numel() else 0, len(_MOVES), dtype=screen.dtype,
                          device=screen.device)
    for k, (drow, dcol) in enumerate(_MOVES):
        leaves = alone & ~in_group(pixel[:, 0] - drow, pixel[:, 1] - dcol)
        cell, on_screen, holds = pixel_at(pixel[:, 0] + drow, pixel[:, 1] + dcol)
        arrives = on_screen & ~in_group(pixel[:, 0] + drow, pixel[:, 1] + dcol) & (covering.take(cell) == 0)
        change = leaves * leave_change + arrives * torch.where(holds, -1.0, 1.0).to(screen.dtype)
        changes[:, k].index_add_(0, group, change)
    mismatch = ((covering > 0) ^ flat_target).sum().to(screen.dtype)
    return changes, mismatch


def _crossing_kernel(distance: torch.Tensor) -> torch.Tensor:
    """``max(0, 1 - d / CROSSING_WIDTH)`` rounded down to a multiple of ``1 / CROSSING_STEPS`` (``d`` metres)."""
    return torch.floor(torch.clamp(1.0 - distance / CROSSING_WIDTH, min=0.0) * CROSSING_STEPS) / CROSSING_STEPS


def _group_crossing(screen, depth, config, landed, block, landing, target, zoom, camera: Camera):
    """The kernel-weighted, one-sided discrete derivative of the exact zoom-0 pixel mismatch, per rigid group.

    The objective is CMA-ES's (Table 3). It is a step function of theta: it changes only where a rigid group
    (:func:`rigid_groups`) crosses a pixel boundary. For each group and axis the rule reads the two crossings
    next to the current theta, one per direction: how far theta must move for the group to cross (metres:
    ``(1 - frac) / g`` ahead and ``frac / g`` behind, ``frac`` the group's sub-pixel position, ``g = f' / z``
    its screen pixels per metre) and what the crossing changes (:func:`group_move_changes`, the group alone
    moving one pixel). A crossing that lowers the count pulls theta towards it by the amount it lowers it,
    weighted by :func:`_crossing_kernel` of its distance (zero beyond :data:`CROSSING_WIDTH`); crossings that
    raise the count pull nothing. Per axis the group's flow is

        ``scale * (lower(-e) K(d(-e)) - lower(+e) K(d(+e)))``,   ``lower(e) = max(0, -change(e))``

    carried by the group's first point (every other point gets 0): with the quantised kernel and the power-of-two
    :data:`CROSSING_SCALE` each value is an exact binary fraction, so the summed flow does not depend on the
    order of summation. Without noise the count is 0 at theta*, no crossing lowers it and theta* is an exact
    fixed point. It reads no loss at another theta: each group's two crossings are local facts of the current
    rendering, as a rasteriser's edge gradient is.

    Returns ``(flow, loss, matched)`` as :func:`~sdm.mapping.flow.dynamic_flow`, except that ``loss`` is the
    mismatch count itself (pixels summed over the batch), not metres.
    """
    flow = torch.zeros_like(screen)
    if screen.shape[0] == 0:
        return flow, screen.new_zeros(()), landing_matched(config, landed, landing, target)
    group, first = rigid_groups(screen, depth, config)
    changes, loss = group_move_changes(screen, group, config, target)  # (G, 4): y+, y-, x+, x-
    lowers = torch.relu(-changes)
    group_screen = screen.index_select(0, first)
    sub_pixel = group_screen - torch.floor(group_screen)  # (G, 2) (row, col)
    group_depth = depth.index_select(0, first)
    gain = torch.stack((camera.fy * camera.rows_per_image_pixel / group_depth,
                        camera.fx * camera.cols_per_image_pixel / group_depth), 1)  # (G, 2) pixels per metre
    ahead, behind = _crossing_kernel((1.0 - sub_pixel) / gain), _crossing_kernel(sub_pixel / gain)
    pull_y = lowers[:, 1] * behind[:, 0] - lowers[:, 0] * ahead[:, 0]
    pull_x = lowers[:, 3] * behind[:, 1] - lowers[:, 2] * ahead[:, 1]
    flow.index_copy_(0, first, CROSSING_SCALE * torch.stack((pull_x, pull_y), 1))
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
    # Issue 20: the kernel-weighted discrete derivative of CMA-ES's objective at zoom 0, eq. 19 at the coarser levels.
    "group_crossing": by_zoom(_group_crossing, dynamic_flow, finest_coarse=CROSSING_FINEST_COARSE),
}

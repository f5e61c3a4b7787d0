"""``group_crossing``: a gradient flow built from CMA-ES's objective, the exact zoom-0 pixel mismatch.

docs/method/floor.md, "A rule aimed at the floor". Table 4 trains ``closed_centred_r1`` and then refines with this
rule at zoom 0 (:class:`sdm.train.Refinement`); :data:`sdm.RULES` registers it as ``"group_crossing"``
(eq. 19 at the zooms ``>= CROSSING_FINEST_COARSE``, :func:`group_crossing_flow` below them). The compiled
trainer runs the same arithmetic (``crossing_pull`` in ``kernel/crossing.c``), held to this module's to the bit by
``tests/mapping/test_native.py`` and ``tests/train/test_refine.py``; ``tests/flow_reference.py`` recounts the mismatch from
scratch for :func:`group_move_changes`.

Shapes and signature: those of :mod:`sdm.mapping.rules`.
"""
from __future__ import annotations

import math
from numbers import Real

import torch

from ..camera import Camera
from ..errors import SDMInputError
from .flow import landing_matched

#: The four one-pixel moves: ``(drow, dcol)`` for y+, y-, x+, x-.
_MOVES = ((1, 0), (-1, 0), (0, 1), (0, -1))

#: ``group_crossing``'s kernel half-width in metres of theta (docs/method/floor.md, "A rule aimed at the floor"):
#: the rule's own, and the last refinement pass's (:attr:`sdm.train.Refinement.last_width`).
CROSSING_WIDTH = 2e-3
#: ``group_crossing``'s flow scale (a power of two: the scaled flow stays a multiple of ``1 / CROSSING_STEPS``).
CROSSING_SCALE = 8.0
#: The kernel is quantised to multiples of ``1 / CROSSING_STEPS``: every flow value is then an exact binary
#: fraction, so its sum over points is the same in any order (float64).
CROSSING_STEPS = 4096
#: ``group_crossing`` is eq. 19 at the zooms ``>=`` this one (its crossing flow reads zoom 0's pixels).
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

    The mismatch of a configuration is CMA-ES's objective (:mod:`sdm.experiments.baselines.cmaes`): the pixels covered by
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


def _crossing_kernel(distance: torch.Tensor, width: float) -> torch.Tensor:
    """``max(0, 1 - d / width)`` rounded down to a multiple of ``1 / CROSSING_STEPS`` (``d``, ``width`` metres)."""
    return torch.floor(torch.clamp(1.0 - distance / width, min=0.0) * CROSSING_STEPS) / CROSSING_STEPS


def check_crossing_width(width, name: str = "width") -> float:
    """``width`` as a float: a kernel half-width in metres, positive and finite; :class:`SDMInputError` naming
    ``name`` otherwise (a bool or a string is not a width)."""
    if isinstance(width, bool) or not isinstance(width, Real) or not (math.isfinite(width) and width > 0):
        raise SDMInputError(f"{name} must be a positive finite number of metres (group_crossing's kernel "
                            f"half-width), got {width!r}")
    return float(width)


def group_crossing_flow(screen, depth, config, landed, block, landing, target, zoom, camera: Camera,
                        width: float = CROSSING_WIDTH):
    """The kernel-weighted, one-sided discrete derivative of the exact zoom-0 pixel mismatch, per rigid group.

    The objective is CMA-ES's (Table 3). It is a step function of theta: it changes only where a rigid group
    (:func:`rigid_groups`) crosses a pixel boundary. For each group and axis the rule reads the two crossings
    next to the current theta, one per direction: how far theta must move for the group to cross (metres:
    ``(1 - frac) / g`` ahead and ``frac / g`` behind, ``frac`` the group's sub-pixel position, ``g = f' / z``
    its screen pixels per metre) and what the crossing changes (:func:`group_move_changes`, the group alone
    moving one pixel). A crossing that lowers the count pulls theta towards it by the amount it lowers it,
    weighted by :func:`_crossing_kernel` of its distance (zero beyond ``width``, metres of theta: by default
    :data:`CROSSING_WIDTH`; a refinement pass sets its own, :attr:`sdm.train.Refinement.widths`); crossings that
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
    ahead, behind = _crossing_kernel((1.0 - sub_pixel) / gain, width), _crossing_kernel(sub_pixel / gain, width)
    pull_y = lowers[:, 1] * behind[:, 0] - lowers[:, 0] * ahead[:, 0]
    pull_x = lowers[:, 3] * behind[:, 1] - lowers[:, 2] * ahead[:, 1]
    flow.index_copy_(0, first, CROSSING_SCALE * torch.stack((pull_x, pull_y), 1))
    return flow, loss, landing_matched(config, landed, landing, target)

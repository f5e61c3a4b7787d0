"""Alternative gradient rules (beyond the paper): selectable by name, same inputs as the paper's flow.

Every rule is a function with the signature of :func:`~sdm.mapping.flow.dynamic_flow`
``(screen, depth, config, landed, block, landing, target, zoom, camera) -> (flow, loss, matched)``
and plugs into the same autograd layer (``SpatialDomainMapping(flow=NAME)``,
``TrainSettings(flow=NAME)``). ``"paper"`` is the paper's eq. 19, unchanged.

Why alternatives (docs/method.md, "Beyond the paper"): with noisy targets the
paper's summed flow does not vanish at the true shift theta*, so SGD settles
beyond it. The rules below change *which* points are pulled and *how much*,
each keeping theta* an exact fixed point without noise (no point is unmatched
there, so no rule pulls anything).

The one that meets the issue's bar at every noise level on the default data is
``"closed_centred_r1"``: eq. 19 at every zoom >= 1 (the coarse levels, where
blocks are wider than the noise's holes and the paper's strong pull brings theta
near theta*), and at zoom 0 a 3x3 closing of the target with the window centred
on the landing block (measured and derived in docs/method.md).

Shapes follow :func:`~sdm.mapping.flow.dynamic_flow`: ``screen`` ``(P, 2)`` float
``(row, col)`` screen pixels, ``depth`` ``(P,)`` metres, ``config`` ``(P,)`` int64,
``landed`` ``(P,)`` bool, ``block``/``landing`` ``(P, 2)`` int64 blocks at level
``zoom``, ``target`` ``(n, H / 2^zoom, W / 2^zoom)`` bool; all on one device (any).
Outputs: ``flow`` ``(P, 2)`` ``(x, y)`` (dtype of ``screen``), ``loss`` ``()`` metres,
``matched`` ``(P,)`` bool.
"""
from __future__ import annotations

from typing import Callable

import torch
import torch.nn.functional as F

from ..camera import Camera
from ..errors import SDMInputError
from .flow import dynamic_flow, pull_loss, window_offsets

FlowRule = Callable[..., tuple[torch.Tensor, torch.Tensor, torch.Tensor]]


def _window(screen, config, landed, block, landing, target, zoom):
    """The 3x3 window of every unmatched landed point: who is pulled, by which blocks, from where.

    Returns:
        ``(matched, pulled, offset, weight)``: ``matched`` ``(P,)`` bool; ``pulled`` ``(p,)``
        int64 indices of the pulled points; ``offset`` ``(p, 9, 2)`` ``(row, col)`` screen
        pixels from each window block's centre to the point (``p - T_q``); ``weight``
        ``(p, 9)`` bool, block ``q`` is active, on the grid and not the landing block
        (the paper's pulling blocks).
    """
    grid_h, grid_w = target.shape[1:]
    flat_target = target.reshape(-1)
    config_offset = config * (grid_h * grid_w)
    landing_cell = torch.where(landed, config_offset + landing[:, 0] * grid_w + landing[:, 1], 0)
    matched = landed & flat_target.take(landing_cell)
    pulled = (landed & ~matched).nonzero().squeeze(1)
    offsets = window_offsets(screen.device)  # (9, 2)
    window = block.index_select(0, pulled)[:, None, :] + offsets  # (p, 9, 2) blocks
    on_grid = (window[..., 0] >= 0) & (window[..., 0] < grid_h) & (window[..., 1] >= 0) & (window[..., 1] < grid_w)
    cell = torch.where(on_grid, config_offset.index_select(0, pulled)[:, None] + window[..., 0] * grid_w
                       + window[..., 1], 0)
    is_landing = (window == landing.index_select(0, pulled)[:, None, :]).all(-1)
    weight = on_grid & flat_target.take(cell) & ~is_landing
    offset = screen.index_select(0, pulled)[:, None, :] - (window.to(screen.dtype) + 0.5) * (1 << zoom)
    return matched, pulled, offset, weight


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
    uncovered = target.reshape(-1) & ~covered
    pulled = landed.nonzero().squeeze(1)
    centre = landing.index_select(0, pulled)
    window = centre[:, None, :] + window_offsets(screen.device)  # (p, 9, 2)
    on_grid = (window[..., 0] >= 0) & (window[..., 0] < grid_h) & (window[..., 1] >= 0) & (window[..., 1] < grid_w)
    cell = torch.where(on_grid, config_offset.index_select(0, pulled)[:, None] + window[..., 0] * grid_w
                       + window[..., 1], 0)
    weight = on_grid & uncovered.take(cell)
    weight[:, 4] = False  # the landing block itself
    offset = screen.index_select(0, pulled)[:, None, :] - (window.to(screen.dtype) + 0.5) * (1 << zoom)
    return pulled, offset, weight


def _sign_flow(screen, depth, pulled, offset, weight, camera):
    """Flow ``sum_q w_q sign(p - T_q)`` and loss ``sum_q w_q |p - T_q|`` (metres) for weights ``(p, 9)`` float."""
    flow = torch.zeros_like(screen)
    pull = (weight[..., None] * torch.sign(offset)).sum(1)  # (p, 2) (row, col)
    flow.index_copy_(0, pulled, pull.flip(-1))  # (row, col) -> (x, y)
    loss = pull_loss((weight[..., None] * offset.abs()).sum(1), depth.index_select(0, pulled), camera)
    return flow, loss


def _reached(screen, landing, zoom):
    """``(P,)`` bool: the point's landing block is the block its projection falls in (the kernel did not clamp it).

    A point that the 3x3 kernel stopped short of its projection is still on its
    way; its window does not contain where it is going, so its pull says little
    about the shift and, under noise, drags towards the target's spread-out edge.
    """
    return ((torch.floor(screen).long() >> zoom) == landing).all(1)


def _rule(select=None, weigh=None, prepare=None, centred=False):
    """Build a rule from three optional hooks.

    ``prepare(target, zoom) -> target`` changes the zoomed target used by the
    matching and the pull; ``select(screen, landing, zoom) -> (P,) bool`` limits
    the points that may be pulled; ``weigh(offset, weight) -> (p, 9) float`` turns
    the paper's pulling blocks into weights. ``centred`` centres the 3x3 window on
    the landing block (where the point is) instead of the input block (where the
    kernel started it).
    """

    def rule(screen, depth, config, landed, block, landing, target, zoom, camera: Camera):
        if prepare is not None:
            target = prepare(target, zoom)
        if select is not None:
            landed = landed & select(screen, landing, zoom)
        window_centre = landing if centred else block
        matched, pulled, offset, weight = _window(screen, config, landed, window_centre, landing, target, zoom)
        weights = weigh(offset, weight) if weigh is not None else weight.to(screen.dtype)
        flow, loss = _sign_flow(screen, depth, pulled, offset, weights, camera)
        return flow, loss, matched

    return rule


def _two_sided(prepare=None, reverse_prepare=None):
    """The one-sided rule on ``prepare(target)`` plus the reverse pull of uncovered blocks of the target.

    The forward side is :func:`_rule` ``(prepare=prepare)``: unmatched points are
    pulled towards the active blocks of their window. The reverse side pulls every
    landed point towards the blocks of the 3x3 window around its landing block that
    are active in the target but covered by no point's projection (a Chamfer loss's
    second direction), by the same ``sign(p - T_q)``. A closing must not be used on
    the reverse side (``reverse_prepare``) unless it adds no block without noise: the
    blocks it adds would be uncovered at theta*.
    """
    forward = _rule(prepare=prepare)

    def rule(screen, depth, config, landed, block, landing, target, zoom, camera: Camera):
        flow, loss, matched = forward(screen, depth, config, landed, block, landing, target, zoom, camera)
        reverse_target = reverse_prepare(target, zoom) if reverse_prepare is not None else target
        pulled, offset, weight = _uncovered_window(screen, config, landed, landing, reverse_target, zoom, camera)
        reverse_flow, reverse_loss = _sign_flow(screen, depth, pulled, offset, weight.to(screen.dtype), camera)
        return flow + reverse_flow, loss + reverse_loss, matched

    return rule


def _by_zoom(fine, coarse, finest_coarse: int = 1):
    """``coarse`` at the loss levels ``zoom >= finest_coarse``, ``fine`` below them."""

    def rule(screen, depth, config, landed, block, landing, target, zoom, camera: Camera):
        chosen = coarse if zoom >= finest_coarse else fine
        return chosen(screen, depth, config, landed, block, landing, target, zoom, camera)

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


def _closing(size: int):
    """Morphological closing of the zoomed target with a ``size x size`` square: fills the holes noise leaves.

    ``(n, h, w)`` bool in, ``(n, h, w)`` bool out, on the target's device. Dilation
    then erosion (max pools over float32 images ``(n, 1, h, w)``); beyond the grid
    the erosion sees active blocks, so closing never removes a block at the border.
    Closing only adds blocks, so a point matched at theta* stays matched: without
    noise theta* stays an exact fixed point (``tests/test_flow_rules.py``).
    """
    pad = size // 2

    def close(target, zoom):
        image = target[:, None].to(torch.float32)
        dilated = F.max_pool2d(image, size, stride=1, padding=pad)
        eroded = -F.max_pool2d(-F.pad(dilated, (pad, pad, pad, pad), value=1.0), size, stride=1)
        return eroded[:, 0] > 0.5

    return close


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
            closings[blocks] = _closing(2 * blocks + 1)
        return closings[blocks](target, zoom)

    return close


#: The gradient rules by name. ``"paper"`` is eq. 19 (:func:`~sdm.mapping.flow.dynamic_flow`), the default.
FLOW_RULES: dict[str, FlowRule] = {
    "paper": dynamic_flow,
    "nearest": _rule(weigh=_nearest),
    "normalised": _rule(weigh=_normalised),
    "reached": _rule(select=_reached),
    "closed": _rule(prepare=_closing(3)),
    "closed5": _rule(prepare=_closing(5)),
    "closed7": _rule(prepare=_closing(7)),
    "closed_r2": _rule(prepare=_closing_pixels(2)),
    "closed_r3": _rule(prepare=_closing_pixels(3)),
    "closed_r4": _rule(prepare=_closing_pixels(4)),
    "closed_m2": _rule(prepare=_closing_pixels(2, at_least=1)),
    "centred": _rule(centred=True),
    "closed_centred": _rule(prepare=_closing(3), centred=True),
    # 3x3 closing at zoom 0 only (radius 1 screen pixel), eq. 19 at the coarser levels.
    "closed_r1": _rule(prepare=_closing_pixels(1)),
    # ... and at zoom 0 the window centred on the landing block: the recommended rule.
    "closed_centred_r1": _by_zoom(_rule(prepare=_closing(3), centred=True), dynamic_flow),
    # Chamfer-like: also pulled towards target blocks that no point's projection covers.
    "two_sided": _two_sided(),
    "closed_two_sided": _two_sided(prepare=_closing(3)),
}


def flow_rule(rule: str | FlowRule) -> FlowRule:
    """The rule function for a name of :data:`FLOW_RULES` (a callable passes through).

    Raises:
        SDMInputError: an unknown name (naming the argument ``flow`` and the known names).
    """
    if callable(rule):
        return rule
    if rule not in FLOW_RULES:
        raise SDMInputError(f"flow must be one of {sorted(FLOW_RULES)} or a function, got {rule!r}")
    return FLOW_RULES[rule]


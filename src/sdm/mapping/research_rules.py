"""Experimental gradient rules: the experiments of docs/method/rules.md; no table uses them.

The aim is a rule that is unbiased under noise. With noisy targets the
paper's summed flow does not vanish at the true shift theta*, so SGD settles
beyond it. The rules here change *which* points are pulled and *how much*, each
keeping theta* an exact fixed point without noise (no point is unmatched there,
so no rule pulls anything). They were measured (docs/method/rules.md, its tables of
Table 2 per rule and of the flow at theta*); the one that met the bar,
``closed_centred_r1``, is in :data:`sdm.FLOW_RULES` with the paper's rule, and no
configuration or table of the workflow uses the ones below.

Each is a :class:`~sdm.mapping.rules.Rule` (``experiment=True``, no compiled form) registered in
:data:`sdm.mapping.rules.RULES` when :mod:`sdm.mapping` is imported; :data:`RESEARCH_RULES` is the registry's
view of them. Selecting one: by name wherever a rule is named (``TrainSettings(rule="closed")``,
``SpatialDomainMapping(rule="closed")``, ``research.rules.names`` of the workflow,
``benchmarks/studies/flow_rules.py --rules``), or as the object itself
(``SpatialDomainMapping(rule=RESEARCH_RULES["nearest"])``).

Shapes and signature: those of :mod:`sdm.mapping.rules`.
"""
from __future__ import annotations

import torch

from ..camera import Camera
from .flow import block_window, nine
from .rules import RULES, FlowRule, Rule, closing, sign_flow, window_rule


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
    """Closing with a square of ``radius`` *screen pixels*: ``2 (radius >> zoom) + 1`` blocks at zoom ``zoom``.

    Noise moves a pixel by at most ``noise_level`` screen pixels, so it opens holes of
    that size at full resolution; zooming out already fills them once a block is
    wider than the noise. A closing of a fixed number of *blocks* (``closed5``)
    over-fills the coarse zooms (5 blocks of 16 pixels bridge whole gaps between
    cars, every point is matched, theta hardly moves until the fine zooms, where
    the 3x3 kernel can no longer reach). Measured in docs/method/rules.md. ``at_least``
    blocks of radius are closed at every zoom (``closed_m2``: 1, i.e. 3x3 at the
    coarse zooms, as ``closed``).
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


#: The experiments, registered in :data:`sdm.mapping.rules.RULES`; none has a compiled form.
_EXPERIMENTS = {
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
    # 3x3 closing at zoom 0 only (radius 1 screen pixel), eq. 19 at the coarser zooms.
    "closed_r1": window_rule(prepare=_closing_pixels(1)),
    # Chamfer-like: also pulled towards target blocks that no point's projection covers.
    "two_sided": _two_sided(),
    "closed_two_sided": _two_sided(prepare=closing(3)),
}
for _name, _flow in _EXPERIMENTS.items():
    RULES.register(Rule(_name, _flow, experiment=True))

#: The experimental rules by name (docs/method/rules.md), a live view of :data:`sdm.mapping.rules.RULES`; no
#: table uses one.
RESEARCH_RULES = RULES.view(experiment=True)

"""The gradient rules the product uses, by name: the paper's eq. 19 and the recommended ``closed_centred_r1``.

Every rule is a function with the signature of :func:`~sdm.mapping.flow.dynamic_flow`
``(screen, depth, config, landed, block, landing, target, zoom, camera) -> (flow, loss, matched)``
and plugs into the same autograd layer (``SpatialDomainMapping(flow=NAME)``,
``TrainSettings(flow=NAME)``). ``"paper"`` is the paper's eq. 19, unchanged.

:data:`FLOW_RULES` holds the rules a configuration or table of this project uses.
``"closed_centred_r1"`` docs/method/rules.md is eq. 19 at every
zoom >= 1 (the coarse levels, where blocks are wider than the noise's holes and
the paper's strong pull brings theta near theta*), and at zoom 0 a 3x3 closing
of the target with the window centred on the landing block: the one rule that
meets the bar "half the paper's mean" at every noise level on the default data.
The other rules measured there are experiments, in :mod:`sdm.mapping.research_rules`
(:data:`~sdm.mapping.research_rules.RESEARCH_RULES`); :func:`flow_rule` finds a
name in either registry. This module also holds the builders they share: one
generic 3x3 window with hooks (:func:`window_rule`), :func:`by_zoom` and
:func:`closing`.

Shapes follow :func:`~sdm.mapping.flow.dynamic_flow`: ``screen`` ``(P, 2)`` float
``(row, col)`` screen pixels, ``depth`` ``(P,)`` metres, ``config`` ``(P,)`` int64,
``landed`` ``(P,)`` bool, ``block``/``landing`` ``(P, 2)`` int64 blocks at level
``zoom``, ``target`` ``(n, H / 2^zoom, W / 2^zoom)`` bool; all on one device (any).
Outputs: ``flow`` ``(P, 2)`` ``(x, y)`` (dtype of ``screen``), ``loss`` ``()`` metres,
``matched`` ``(P,)`` bool.
"""
from __future__ import annotations

import functools
from typing import Callable

import torch

from ..camera import Camera
from ..errors import SDMInputError
from .crossing import CROSSING_FINEST_COARSE, CROSSING_WIDTH, check_crossing_width, group_crossing_flow
from .flow import block_window, dynamic_flow, landing_matched, nine, pull_loss

FlowRule = Callable[..., tuple[torch.Tensor, torch.Tensor, torch.Tensor]]


def _window(screen, config, landed, centre, landing, target, zoom):
    """The 3x3 window around ``centre`` of every unmatched landed point: who is pulled, by which blocks, from where.

    Returns:
        ``(matched, pulled, offset, weight)``: ``matched`` ``(P,)`` bool; ``pulled`` ``(p,)``
        int64 indices of the pulled points; ``offset`` ``(p, 9, 2)`` ``(row, col)`` screen
        pixels from each window block's centre to the point (``p - T_q``); ``weight``
        ``(p, 9)`` bool, block ``q`` is active, on the grid and not the landing block
        (the paper's pulling blocks).
    """
    matched = landing_matched(config, landed, landing, target)
    pulled = (landed & ~matched).nonzero().squeeze(1)
    window = block_window(centre.index_select(0, pulled), config.index_select(0, pulled), target, zoom, screen.dtype)
    offset = nine(window.offset(screen.index_select(0, pulled)))
    return matched, pulled, offset, window.pulling(landing.index_select(0, pulled))


def sign_flow(screen, depth, pulled, offset, weight, camera):
    """Flow ``sum_q w_q sign(p - T_q)`` and loss ``sum_q w_q |p - T_q|`` (metres) for weights ``(p, 9)`` float.

    ``offset`` ``(p, 9, 2)`` screen pixels of the points ``pulled`` ``(p,)`` (indices into
    ``screen`` ``(P, 2)`` and ``depth`` ``(P,)``). Returns ``flow`` ``(P, 2)`` ``(x, y)``, ``loss`` ``()``.
    """
    flow = torch.zeros_like(screen)
    pull = (weight[..., None] * torch.sign(offset)).sum(1)  # (p, 2) (row, col)
    flow.index_copy_(0, pulled, pull.flip(-1))  # (row, col) -> (x, y)
    loss = pull_loss((weight[..., None] * offset.abs()).sum(1), depth.index_select(0, pulled), camera)
    return flow, loss


def window_rule(select=None, weigh=None, prepare=None, centred=False) -> FlowRule:
    """Build a rule from three optional hooks on the paper's 3x3 window (no hook: eq. 19).

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
        flow, loss = sign_flow(screen, depth, pulled, offset, weights, camera)
        return flow, loss, matched

    return rule


def by_zoom(fine: FlowRule, coarse: FlowRule, finest_coarse: int = 1) -> FlowRule:
    """``coarse`` at the loss levels ``zoom >= finest_coarse``, ``fine`` below them."""

    def rule(screen, depth, config, landed, block, landing, target, zoom, camera: Camera):
        chosen = coarse if zoom >= finest_coarse else fine
        return chosen(screen, depth, config, landed, block, landing, target, zoom, camera)

    return rule


def closing(size: int):
    """Morphological closing of the zoomed target with a ``size x size`` square: fills the holes noise leaves.

    ``(n, h, w)`` bool in, ``(n, h, w)`` bool out, on the target's device. Dilation
    (a block becomes active where any block of its square is; beyond the grid there is
    none) then erosion (it stays active where every block of its square is; beyond the
    grid the erosion sees active blocks, so closing never removes a block at the
    border). Both are separable: rows, then columns, each an OR (AND) of shifted
    bool views, exact and about 10x cheaper than max pools over float images (which
    ``tests/test_flow_rules.py`` holds it equal to). Closing only adds blocks, so a
    point matched at theta* stays matched: without noise theta* stays an exact fixed
    point.
    """
    radius = size // 2

    def close(target, zoom):
        return _spread(_spread(target, radius, torch.Tensor.logical_or_), radius, torch.Tensor.logical_and_)

    return close


def _spread(image: torch.Tensor, radius: int, combine) -> torch.Tensor:
    """``(n, h, w)`` bool: each cell combined (``combine_``: OR or AND, in place) with its neighbours up to
    ``radius`` cells away along rows, then along columns; neighbours beyond the grid are left out."""
    for axis in (1, 2):
        source, image = image, image.clone()
        size = image.shape[axis]
        for shift in range(1, min(radius, size - 1) + 1):
            combine(image.narrow(axis, shift, size - shift), source.narrow(axis, 0, size - shift))
            combine(image.narrow(axis, 0, size - shift), source.narrow(axis, shift, size - shift))
    return image


#: closed_centred_r1: the 3x3 closing and the centred window below this loss level, eq. 19 from it on.
_CLOSE_3 = closing(3)
_R1_FINEST_COARSE = 1

#: The gradient rules a configuration or table uses, by name. ``"paper"`` is eq. 19
#: (:func:`~sdm.mapping.flow.dynamic_flow`), the default.
FLOW_RULES: dict[str, FlowRule] = {
    "paper": dynamic_flow,
    # 3x3 closing and the window centred on the landing block at zoom 0, eq. 19 at the coarser levels.
    "closed_centred_r1": by_zoom(window_rule(prepare=_CLOSE_3, centred=True), dynamic_flow,
                                 finest_coarse=_R1_FINEST_COARSE),
    # The kernel-weighted discrete derivative of CMA-ES's objective at zoom 0 (sdm.mapping.crossing),
    # eq. 19 at the coarser levels; Table 4 refines closed_centred_r1's runs with it (sdm.train.Refinement).
    "group_crossing": by_zoom(group_crossing_flow, dynamic_flow, finest_coarse=CROSSING_FINEST_COARSE),
}


def crossing_width_rule(name: str, width: float | None) -> FlowRule:
    """Rule ``name`` with ``group_crossing``'s kernel half-width ``width`` (metres; a refinement pass's,
    :attr:`sdm.train.Refinement.widths`). ``width=None``, and every rule but ``"group_crossing"`` (which read no
    width), give :func:`rule_by_name`'s rule itself.

    Raises:
        SDMInputError: an unknown ``name`` (naming ``flow``), a ``width`` that is not a positive finite number.
    """
    rule = rule_by_name(name)
    if name != "group_crossing" or width is None or check_crossing_width(width) == CROSSING_WIDTH:
        return rule
    return by_zoom(functools.partial(group_crossing_flow, width=float(width)), dynamic_flow,
                   finest_coarse=CROSSING_FINEST_COARSE)


def kernel_form(name: str, level: int):
    """How the compiled trainer (:func:`sdm.mapping.native.train_program`) runs rule ``name`` at loss ``level``.

    Returns:
        ``None`` where the rule has no compiled form (the trainer then takes the torch path); otherwise the
        kernel's flow: ``"paper"`` (eq. 19's window on the input block), ``"centred"`` (the window on the
        landing block, over the target closed as ``closing(3)`` closes it) or ``"crossing"``
        (``group_crossing``'s flow). Read from the same constants that build :data:`FLOW_RULES`, so the two
        cannot drift.
    """
    if name == "paper":
        return "paper"
    if name == "closed_centred_r1":  # window_rule(prepare=_CLOSE_3, centred=True) below the coarse levels
        return "paper" if level >= _R1_FINEST_COARSE else "centred"
    if name == "group_crossing":
        return "paper" if level >= CROSSING_FINEST_COARSE else "crossing"
    return None


def rule_by_name(name: str) -> FlowRule:
    """The rule named ``name`` in :data:`FLOW_RULES` or, failing that, in the experiments' ``RESEARCH_RULES``.

    Raises:
        SDMInputError: not a name of either (naming the argument ``flow`` and both registries' names).
    """
    # Imported here: the experiments are built from this module's builders.
    from .research_rules import RESEARCH_RULES

    if isinstance(name, str):
        if name in FLOW_RULES:
            return FLOW_RULES[name]
        if name in RESEARCH_RULES:
            return RESEARCH_RULES[name]
    raise SDMInputError(f"flow must be a rule of sdm.FLOW_RULES {sorted(FLOW_RULES)} or an experiment of "
                        f"sdm.mapping.research_rules.RESEARCH_RULES {sorted(RESEARCH_RULES)}, got {name!r}")


def flow_rule(rule: str | FlowRule) -> FlowRule:
    """The rule function for a name (:func:`rule_by_name`); a callable passes through.

    Raises:
        SDMInputError: an unknown name (naming the argument ``flow`` and the known names).
    """
    return rule if callable(rule) else rule_by_name(rule)

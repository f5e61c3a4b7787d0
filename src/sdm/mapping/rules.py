"""Gradient rules as objects (:class:`Rule`) and their one registry, :data:`RULES`.

A rule is a name, its torch flow, and optionally its compiled form: the flow the compiled trainer
(:func:`sdm.mapping.native.train_program`) runs at each loss zoom (:class:`KernelFlow`). Every rule of the
project is registered in :data:`RULES`; :data:`FLOW_RULES` (the rules a configuration or table uses) and
:data:`sdm.mapping.research_rules.RESEARCH_RULES` (the experiments of docs/method/rules.md) are live views of
it, and the workflow schema's rule names are held to it by ``tests/experiments/test_research.py``.

Wherever a rule is named (``SpatialDomainMapping(rule=...)``, ``TrainSettings(rule=...)``) it may be a
registered name, a :class:`Rule`, or a bare function with the signature of
:func:`~sdm.mapping.flow.dynamic_flow` ``(screen, depth, config, landed, block, landing, target, zoom, camera)
-> (flow, loss, matched)`` (:meth:`RuleRegistry.resolve`; a bare function has no compiled form, so it trains on the torch
path). ``"paper"`` is the paper's eq. 19, unchanged, and the default.

The product's rules: ``"paper"``; ``"closed_centred_r1"`` (docs/method/rules.md), eq. 19 at every zoom >= 1 (the
coarse zooms, where blocks are wider than the noise's holes and the paper's strong pull brings theta near
theta*), and at zoom 0 a 3x3 closing of the target with the window centred on the landing block: the one rule
that meets the bar "half the paper's mean" at every noise level on the default data; ``"group_crossing"``
(:mod:`sdm.mapping.crossing`), Table 4's refinement. This module also holds the builders every rule shares: one
generic 3x3 window with hooks (:func:`window_rule`), :func:`by_zoom` and :func:`closing`.

Shapes follow :func:`~sdm.mapping.flow.dynamic_flow`: ``screen`` ``(P, 2)`` float
``(row, col)`` screen pixels, ``depth`` ``(P,)`` metres, ``config`` ``(P,)`` int64,
``landed`` ``(P,)`` bool, ``block``/``landing`` ``(P, 2)`` int64 blocks at zoom
``zoom``, ``target`` ``(n, H / 2^zoom, W / 2^zoom)`` bool; all on one device (any).
Outputs: ``flow`` ``(P, 2)`` ``(x, y)`` (dtype of ``screen``), ``loss`` ``()`` metres,
``matched`` ``(P,)`` bool.

>>> from sdm.mapping.rules import RULES
>>> RULES["closed_centred_r1"].kernel_flows([2, 1, 0])
[<KernelFlow.PAPER: 0>, <KernelFlow.PAPER: 0>, <KernelFlow.CENTRED: 1>]
>>> RULES["nearest"].kernel_flows([0]) is None  # an experiment: the torch path
True
"""
from __future__ import annotations

import enum
import functools
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
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
    """``coarse`` at the loss zooms ``zoom >= finest_coarse``, ``fine`` below them."""

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
    ``tests/mapping/test_flow_rules.py`` holds it equal to). Closing only adds blocks, so a
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


class KernelFlow(enum.IntEnum):
    """A flow the compiled trainer (``sdm_train``, ``kernel/train.c``) runs at one loss zoom; the value is its mode."""

    #: eq. 19's window on the input block (:func:`~sdm.mapping.flow.dynamic_flow`)
    PAPER = 0
    #: the window on the landing block, over the zoom's target closed as :func:`closing` ``(3)`` closes it
    CENTRED = 1
    #: ``group_crossing``'s flow (:func:`~sdm.mapping.crossing.group_crossing_flow`; zoom 0 only)
    CROSSING = 2


@dataclass(frozen=True, repr=False)
class Rule:
    """A gradient rule: its name, its torch flow and, optionally, its compiled form.

    Attributes:
        name: the name it is registered (and written in tables) under.
        flow: the torch flow, a function with :func:`~sdm.mapping.flow.dynamic_flow`'s signature; a rule is
            also callable itself, as its flow.
        compiled: ``None`` (no compiled form: training takes the torch path) or the :class:`KernelFlow` the
            compiled trainer runs where the rule is not eq. 19; it must give ``flow``'s theta history to the
            bit (``tests/mapping/test_native.py`` holds the product's rules to that).
        finest_coarse: ``None``, or the loss zoom from which on the rule is eq. 19 (:class:`KernelFlow` ``PAPER``
            in the kernel; :meth:`by_zoom` builds ``flow`` from the same number).
        experiment: measured in docs/method/rules.md, used by no table (:data:`RESEARCH_RULES` rather than
            :data:`FLOW_RULES`).

    >>> from sdm.mapping.flow import dynamic_flow
    >>> mine = Rule("mine", dynamic_flow, KernelFlow.PAPER)
    >>> mine.kernel_flows([1, 0])
    [<KernelFlow.PAPER: 0>, <KernelFlow.PAPER: 0>]
    >>> Rule("torch_only", dynamic_flow).kernel_flows([1, 0]) is None
    True
    """

    name: str
    flow: FlowRule
    compiled: KernelFlow | None = None
    finest_coarse: int | None = None
    experiment: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise SDMInputError(f"Rule name must be a non-empty string, got {self.name!r}")
        if not callable(self.flow):
            raise SDMInputError(f"Rule {self.name!r}: flow must be a function with dynamic_flow's signature, "
                                f"got {type(self.flow).__name__}")
        if self.compiled is not None and not isinstance(self.compiled, KernelFlow):
            raise SDMInputError(f"Rule {self.name!r}: compiled must be a KernelFlow or None, got {self.compiled!r}")
        if self.finest_coarse is not None and (isinstance(self.finest_coarse, bool)
                                               or not isinstance(self.finest_coarse, int) or self.finest_coarse < 0):
            raise SDMInputError(f"Rule {self.name!r}: finest_coarse must be a non-negative integer or None, "
                                f"got {self.finest_coarse!r}")

    @classmethod
    def by_zoom(cls, name: str, fine: FlowRule, finest_coarse: int, compiled: KernelFlow | None = None,
                experiment: bool = False) -> "Rule":
        """``fine`` below loss zoom ``finest_coarse``, eq. 19 from it on: the torch flow (:func:`by_zoom`) and the
        compiled form's switch read the same number."""
        return cls(name, by_zoom(fine, dynamic_flow, finest_coarse), compiled, finest_coarse, experiment)

    def __call__(self, screen, depth, config, landed, block, landing, target, zoom, camera: Camera):
        return self.flow(screen, depth, config, landed, block, landing, target, zoom, camera)

    def __repr__(self) -> str:
        compiled = f", compiled={self.compiled.name}" if self.compiled is not None else ""
        return f"Rule({self.name!r}{compiled})"

    def kernel_flows(self, zooms: Iterable[int]) -> list[KernelFlow] | None:
        """The compiled trainer's flow at each of ``zooms``, or ``None`` where the rule has no compiled form."""
        if self.compiled is None:
            return None
        coarse = self.finest_coarse
        return [KernelFlow.PAPER if coarse is not None and zoom >= coarse else self.compiled for zoom in zooms]


class RuleRegistry(Mapping):
    """The registered rules by name (a read-only mapping; :meth:`register` adds one).

    >>> from sdm.mapping.rules import RULES
    >>> sorted(RULES.view(experiment=False))
    ['closed_centred_r1', 'group_crossing', 'paper']
    >>> RULES.resolve("paper")
    Rule('paper', compiled=PAPER)
    """

    def __init__(self) -> None:
        self._rules: dict[str, Rule] = {}

    def __getitem__(self, name: str) -> Rule:
        return self._rules[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._rules)

    def __len__(self) -> int:
        return len(self._rules)

    def register(self, rule: Rule) -> Rule:
        """Add ``rule`` under its name, and return it; :class:`SDMInputError` where the name holds another rule."""
        if not isinstance(rule, Rule):
            raise SDMInputError(f"register takes a sdm.mapping.rules.Rule, got {type(rule).__name__}")
        if self._rules.get(rule.name, rule) != rule:
            raise SDMInputError(f"a rule named {rule.name!r} is already registered: {self._rules[rule.name]!r}")
        self._rules[rule.name] = rule
        return rule

    def unregister(self, name: str) -> None:
        """Remove the rule named ``name`` (:class:`SDMInputError` if there is none)."""
        if name not in self._rules:
            raise SDMInputError(f"no rule named {name!r} is registered")
        del self._rules[name]

    def view(self, experiment: bool) -> "RuleView":
        """A live read-only view of the registered rules that are (``True``) or are not experiments."""
        return RuleView(self, experiment)

    def resolve(self, rule) -> Rule:
        """The :class:`Rule` of ``rule``: a registered name, a :class:`Rule` (as it is) or a bare flow function
        (a :class:`Rule` without compiled form, named after it).

        Raises:
            SDMInputError: an unknown name or anything else (naming the argument ``rule`` and the registered names).
        """
        if isinstance(rule, Rule):
            return rule
        if isinstance(rule, str) and rule in self._rules:
            return self._rules[rule]
        if callable(rule) and not isinstance(rule, str):
            return Rule(getattr(rule, "__qualname__", type(rule).__name__), rule)
        raise SDMInputError(f"rule must be a rule of sdm.mapping.rules.RULES {sorted(self._rules)}, a Rule or a "
                            f"flow function, got {rule!r}")


class RuleView(Mapping):
    """The rules of a :class:`RuleRegistry` that are, or are not, experiments: live, read-only, ``|``-able."""

    def __init__(self, registry: RuleRegistry, experiment: bool) -> None:
        self._registry, self._experiment = registry, experiment

    def _selected(self) -> dict[str, Rule]:
        return {name: rule for name, rule in self._registry.items() if rule.experiment == self._experiment}

    def __getitem__(self, name: str) -> Rule:
        rule = self._registry[name]
        if rule.experiment != self._experiment:
            raise KeyError(name)
        return rule

    def __iter__(self) -> Iterator[str]:
        return iter(self._selected())

    def __len__(self) -> int:
        return len(self._selected())

    def __or__(self, other: Mapping) -> dict[str, Rule]:
        return self._selected() | dict(other)

    def __ror__(self, other: Mapping) -> dict[str, Rule]:
        return dict(other) | self._selected()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self._selected()!r})"


#: Every gradient rule by name: the product's (below) and the experiments (:mod:`sdm.mapping.research_rules`,
#: registered when :mod:`sdm.mapping` is imported); :meth:`RuleRegistry.register` adds one.
RULES = RuleRegistry()

#: eq. 19 (:func:`~sdm.mapping.flow.dynamic_flow`), the default; the kernel's window on the input block.
PAPER = RULES.register(Rule("paper", dynamic_flow, KernelFlow.PAPER))
#: The 3x3 closing and the window centred on the landing block at zoom 0, eq. 19 at the coarser zooms.
CLOSED_CENTRED_R1 = RULES.register(Rule.by_zoom("closed_centred_r1", window_rule(prepare=closing(3), centred=True),
                                                1, KernelFlow.CENTRED))
#: The kernel-weighted discrete derivative of CMA-ES's objective at zoom 0 (sdm.mapping.crossing), eq. 19 at the
#: coarser zooms; Table 4 refines closed_centred_r1's runs with it (sdm.train.Refinement).
GROUP_CROSSING = RULES.register(Rule.by_zoom("group_crossing", group_crossing_flow, CROSSING_FINEST_COARSE,
                                             KernelFlow.CROSSING))

#: The rules a configuration or table uses, by name (every registered rule that is not an experiment).
FLOW_RULES = RULES.view(experiment=False)


def crossing_width_rule(rule, width: float | None) -> Rule:
    """The rule ``rule`` (:meth:`RuleRegistry.resolve`) with ``group_crossing``'s kernel half-width ``width``
    (metres; a refinement pass's, :attr:`sdm.train.Refinement.widths`). ``width=None``, its own width
    :data:`~sdm.mapping.crossing.CROSSING_WIDTH`, and every rule but ``group_crossing`` (which read no width) give
    the rule itself; another width a :class:`Rule` of the same name and compiled form whose torch flow reads it
    (the compiled trainer reads the width per zoom itself: ``crossing_widths`` of
    :func:`sdm.mapping.native.train_program`).

    Raises:
        SDMInputError: an unknown ``rule`` (naming ``rule``), a ``width`` that is not a positive finite number.
    """
    rule = RULES.resolve(rule)
    if rule is not GROUP_CROSSING or width is None or check_crossing_width(width) == CROSSING_WIDTH:
        return rule
    return Rule.by_zoom(rule.name, functools.partial(group_crossing_flow, width=float(width)), CROSSING_FINEST_COARSE,
                        KernelFlow.CROSSING)

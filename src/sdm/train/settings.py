"""The settings of a training run and what it returns: :class:`TrainSettings`, :class:`Refinement` (the
schedule's passes after the paper's zooms, :func:`parse_schedule`), :class:`History` and :class:`RunsHistory`
(docs/library.md; the training: docs/method/paper.md, "Training and evaluation"; the passes: docs/method/floor.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Integral, Real

import numpy as np
import torch

from ..errors import SDMInputError
from ..mapping.crossing import CROSSING_WIDTH, check_crossing_width
from ..mapping.rules import RULES, Rule


#: The largest shift a run may start from or end at, metres per component of theta (docs/library.md,
#: "Divergence"). The paper's shift is 0.6 m long and Table 6 draws rows 0.15 m apart; a shift of 10 m moves a car
#: 20 m away by a third of the 256-pixel screen (fx * cols_per_image_pixel = 174 pixels per unit of x / z).
#: A theta beyond it is no estimate but a run that diverged (a learning rate too large) or a start the flow
#: cannot correct.
THETA_BOUND = 10.0


@dataclass(frozen=True)
class TrainSettings:
    """Hyper-parameters of one training run.

    Attributes:
        lr: initial learning rate (metres per unit of summed flow).
        n_epoch: passes over the training set per zoom.
        batch_size: configurations per mini-batch.
        s: the coarsest zoom (blocks of ``2^s`` pixels).
        zoom: the finest zoom trained (0 = full resolution).
        lr_decay: factor applied to the learning rate after each zoom.
        seed: seeds the shuffling.
        rule: the gradient rule: a name of :data:`sdm.RULES` (default ``"paper"``, eq. 19), a :class:`sdm.Rule`
            (trained by the compiled kernel where it has a compiled form) or a flow function (the torch path).
        fit_depth: train the general shift ``(a, b, c)`` with the depth flow of :mod:`sdm.depth`
            (beyond the paper); theta, its history and ``final_theta`` then have three entries.
        depth_lr_scale: the learning rate of ``c`` relative to ``lr`` (with ``fit_depth``); 20 by a
            measured sweep (1: c lags, 10-30: within 1e-2 m, 100: diverges; docs/method/depth.md).
        depth_zoom: the finest zoom at which ``c`` moves (with ``fit_depth``; at least the coarsest
            zoom ``s``): the finer zooms train ``(a, b)`` with ``c`` held. Default 1: at full resolution
            the pull on ``c`` with ``depth_lr_scale`` 20 walks along the near-degenerate direction of
            ``(b, c)`` (every point lies below the principal point) and leaves ``b`` off by about 2e-3 m
            at c = -1 m (measured; docs/method/depth.md).
    """

    lr: float = 3e-4
    n_epoch: int = 1
    batch_size: int = 16
    s: int = 4
    zoom: int = 0
    lr_decay: float = 0.5
    seed: int = 0
    rule: str | Rule = "paper"
    fit_depth: bool = False
    depth_lr_scale: float = 20.0
    depth_zoom: int = 1

    def __post_init__(self) -> None:
        # Every field's type first, by name: a string would fail inside math.isfinite with a TypeError
        # naming no field, and a bool would pass as the number 0 or 1 (bool is an int subclass).
        for name in ("lr", "lr_decay", "depth_lr_scale"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, Real):
                raise SDMInputError(f"{name} must be a number, got {value!r} ({type(value).__name__})")
        for name in ("n_epoch", "batch_size", "s", "zoom", "seed", "depth_zoom"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, Integral):  # 2.0 is refused: an epoch count is exact
                raise SDMInputError(f"{name} must be an integer, got {value!r} ({type(value).__name__})")
        if not isinstance(self.fit_depth, bool):
            raise SDMInputError(f"fit_depth must be True or False, got {self.fit_depth!r}")
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise SDMInputError(f"lr must be a positive finite number, got {self.lr!r}")
        for name in ("n_epoch", "batch_size"):
            value = getattr(self, name)
            if int(value) != value or value < 1:
                raise SDMInputError(f"{name} must be a positive integer, got {value!r}")
        if int(self.s) != self.s or self.s < 0:
            raise SDMInputError(f"s must be a non-negative integer, got {self.s!r}")
        if int(self.zoom) != self.zoom or not 0 <= self.zoom <= self.s:
            raise SDMInputError(f"zoom must be an integer in [0, s] = [0, {self.s}], got {self.zoom!r}")
        if not (math.isfinite(self.lr_decay) and self.lr_decay > 0):
            raise SDMInputError(f"lr_decay must be a positive finite number, got {self.lr_decay!r}")
        RULES.resolve(self.rule)  # SDMInputError naming rule: not a registered name, a Rule or a flow function
        if not (math.isfinite(self.depth_lr_scale) and self.depth_lr_scale > 0):
            raise SDMInputError(f"depth_lr_scale must be a positive finite number, got {self.depth_lr_scale!r}")
        if isinstance(self.depth_zoom, bool) or int(self.depth_zoom) != self.depth_zoom or self.depth_zoom < 0:
            raise SDMInputError(f"depth_zoom must be a non-negative integer, got {self.depth_zoom!r}")

    def rate_scale(self, zoom: int, like: torch.Tensor) -> torch.Tensor:
        """``(3,)`` per-parameter learning-rate factors of ``(a, b, c)`` at zoom ``zoom`` (with ``fit_depth``).

        ``(1, 1, depth_lr_scale)``, and ``(1, 1, 0)`` below ``min(depth_zoom, s)``; dtype and device of ``like``.
        """
        depth = self.depth_lr_scale if zoom >= min(self.depth_zoom, self.s) else 0.0
        return torch.tensor([1.0, 1.0, depth], dtype=like.dtype, device=like.device)


@dataclass
class History:
    """What a training run did, step by step (CPU tensors, whatever device trained).

    Attributes:
        theta: ``(steps + 1, 2)`` float64 ``(a, b)`` in metres, before the first step and after each.
        loss: ``(steps,)`` float64 loss ``J`` of each step's batch (metres).
        zoom: ``(steps,)`` int64 zoom level of each step.
        lr: ``(steps,)`` float64 learning rate of each step.
        settings: the settings of the run.
    """

    theta: torch.Tensor
    loss: torch.Tensor
    zoom: torch.Tensor
    lr: torch.Tensor
    settings: TrainSettings

    @property
    def final_theta(self) -> tuple[float, ...]:
        """``(a, b)``, or ``(a, b, c)`` when the run fitted depth."""
        return tuple(self.theta[-1].tolist())

    def to_frame(self):
        """A pandas DataFrame with one row per step: ``step, zoom, lr, loss, a, b`` (theta after the step)."""
        import pandas as pd

        steps = len(self.loss)
        return pd.DataFrame(
            {
                "step": range(1, steps + 1),
                "zoom": self.zoom.tolist(),
                "lr": self.lr.tolist(),
                "loss": self.loss.tolist(),
                "a": self.theta[1:, 0].tolist(),
                "b": self.theta[1:, 1].tolist(),
            }
        )


@dataclass
class RunsHistory:
    """What :func:`train_runs` did: the theta of every run, step by step (CPU tensors).

    Attributes:
        theta: ``(steps + 1, R, 2)`` float64 ``(a, b)`` in metres of each run, before the first step and after
            each; ``(steps + 1, R, 3)`` ``(a, b, c)`` when the runs fitted depth. With parameters attached to
            points (``param_index``), ``(epochs + 1, R, K, 2)``: every row's ``(a, b)`` before the first step and
            after each epoch (a row moves only in the steps that draw its configurations, and ``K`` rows per
            step would make the history ``K`` times the run).
        loss: ``(steps, R)`` float64 loss ``J`` of each run's mini-batch at each step (metres; 0 where the
            run's batch held no point).
        zoom: ``(steps,)`` int64 zoom level of each step.
        lr: ``(steps,)`` float64 learning rate of each step (the same for every run).
        settings: the settings of each run.
        theta_steps: ``(len(theta),)`` int64, the number of steps taken when each entry of ``theta`` was
            recorded (``0, 1, 2, ...`` for the shared shift).
    """

    theta: torch.Tensor
    loss: torch.Tensor
    zoom: torch.Tensor
    lr: torch.Tensor
    settings: list[TrainSettings]
    theta_steps: torch.Tensor | None = None

    def __post_init__(self) -> None:
        if self.theta_steps is None:
            self.theta_steps = torch.arange(self.theta.shape[0], dtype=torch.int64)

    @property
    def final_theta(self) -> list[tuple[float, ...]]:
        """``(a, b)`` (or ``(a, b, c)`` with depth) of each run after its last step."""
        return [tuple(pair) for pair in self.theta[-1].tolist()]


def rates_per_point(param_index: torch.Tensor) -> torch.Tensor:
    """``(K,)`` float64 row rates (``train_runs(row_rate=)``) that make a row's rate per point the same for every row:
    the mean number of points per row over each row's own (points counted once per column that names the row)."""
    rows = param_index.reshape(param_index.shape[0], -1).to(torch.int64)
    counts = torch.bincount(rows.reshape(-1)).to(torch.float64)
    return counts.mean() / counts


@dataclass(frozen=True)
class Refinement:
    """A documented extension of the paper's coarse-to-fine training: SGD steps at the finest zoom with another rule.

    After the zooms ``s .. zoom`` of :class:`TrainSettings`, ``passes`` passes of ``pass_steps`` SGD steps each
    at zoom ``zoom`` with the gradient rule ``rule``; pass ``i`` (from 0) runs at the rate of zoom
    ``zoom + rate_from`` times ``lr_decay^i`` (by default four times the last zoom's rate, then halving each
    pass: the paper's halving, continued per pass), with the chain ``s .. zoom`` of the last zoom
    (:func:`refine_runs`).

    The passes are counted in SGD steps, not in epochs, so the refinement's strength does not depend on the size
    of the training set: 4 passes of 96 steps are 12 epochs of the default's 512 configurations (batches of 16),
    and 192 epochs of a 41-configuration set (docs/method/floor.md, "The schedule that reaches the floor").

    ``closed_centred_r1`` brings theta within a few millimetres, where ``group_crossing`` (whose fixed point is
    near the floor but whose pull far from it is weak) refines it (docs/method/floor.md, "A rule aimed at the floor").

    ``group_crossing`` pulls theta only towards pixel crossings within its kernel's half-width. The passes narrow
    it: the last pass runs at ``last_width`` (the rule's own :data:`~sdm.mapping.crossing.CROSSING_WIDTH`, whose
    fixed point the schedule keeps), each earlier pass at twice the next one's, at most ``first_width``
    (:attr:`widths`; 4 passes: 16, 8, 4, 2e-3 m). On sparse real frames (few rigid groups, 0.2 m of theta per
    pixel) theta ends ``closed_centred_r1``'s zooms farther than 2e-3 m from any crossing that lowers the count;
    the wide first passes, at the full rate, reach them. On dense data the same passes scatter theta by a few
    millimetres; the narrower passes pull it back, given steps enough (96 a pass: docs/method/floor.md, "The
    refinement on the real sample").

    Attributes:
        rule: a rule name, or a :class:`~sdm.mapping.rules.Rule` (:meth:`sdm.mapping.rules.RuleRegistry.resolve`).
        passes: passes, a positive integer.
        rate_from: the first pass's rate is zoom ``zoom + rate_from``'s (a non-negative integer; 2 was chosen
            on runs no table holds: docs/method/floor.md, "The schedule that reaches the floor").
        moves_c: with ``fit_depth``, the passes move ``c`` too (at ``depth_lr_scale`` times their rate), whatever
            ``depth_zoom`` says: ``group_crossing``'s depth flow at theta* under noise is less biased at zoom 0 than
            the paper's rule's at zoom 1 (measured by ``sdm.experiments.depth_bias``: Table 5's ``table5_bias``).
        pass_steps: SGD steps per pass, a positive integer (96: three epochs of the default's 512 configurations;
            chosen on runs no table holds: docs/method/floor.md, "The refinement on the real sample").
        first_width: ``group_crossing``'s widest kernel half-width, metres (positive, at least ``last_width``;
            16e-3 m, chosen on runs no table holds: docs/method/floor.md, "The refinement on the real sample").
        last_width: the last pass's kernel half-width, metres (positive; the rule's own, 2e-3 m).
    """

    rule: str | Rule = "group_crossing"
    passes: int = 4
    rate_from: int = 2
    moves_c: bool = True
    pass_steps: int = 96
    first_width: float = 16e-3
    last_width: float = CROSSING_WIDTH

    def __post_init__(self) -> None:
        RULES.resolve(self.rule)
        for name, least in (("passes", 1), ("rate_from", 0), ("pass_steps", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                kind = "a positive" if least else "a non-negative"
                raise SDMInputError(f"refinement {name} must be {kind} integer, got {value!r}")
        if not isinstance(self.moves_c, bool):
            raise SDMInputError(f"refinement moves_c must be True or False, got {self.moves_c!r}")
        for name in ("first_width", "last_width"):
            check_crossing_width(getattr(self, name), f"refinement {name}")
        if self.first_width < self.last_width:
            raise SDMInputError(f"refinement first_width ({self.first_width!r} m) must be at least last_width "
                                f"({self.last_width!r} m): the passes narrow the kernel")

    @property
    def steps(self) -> int:
        """The refinement's SGD steps, ``passes * pass_steps``."""
        return self.passes * self.pass_steps

    @property
    def widths(self) -> list[float]:
        """``group_crossing``'s kernel half-width of each pass, metres: ``last_width`` on the last pass, twice the
        next pass's on each earlier one, at most ``first_width``."""
        widths, width = [], float(self.last_width)
        for _ in range(self.passes):
            widths.append(width)
            width = min(2.0 * width, float(self.first_width))
        return widths[::-1]

    def rates(self, settings: TrainSettings) -> list[float]:
        """The learning rate of each pass (metres per unit of summed flow): zoom ``zoom + rate_from``'s rate times
        ``lr_decay^i``, whatever the pass's kernel width."""
        rate = settings.lr * settings.lr_decay ** max(settings.s - settings.zoom - self.rate_from, 0)
        return [rate * settings.lr_decay ** i for i in range(self.passes)]


def parse_schedule(name: str) -> tuple[str, Refinement | None]:
    """A training schedule by name: ``"RULE"`` (the paper's coarse-to-fine training, rule ``RULE``) or ``"RULE+REFINE:E"``
    (then ``E`` refinement passes of :attr:`Refinement.pass_steps` SGD steps with rule ``REFINE``,
    :class:`Refinement`; ``"RULE+REFINE"``: 4 passes). Every other choice of the passes is the class's default:
    their rates, and ``group_crossing``'s kernel half-widths narrowing to 2e-3 m on the last pass
    (:attr:`Refinement.widths`: 16, 8, 4, 2e-3 m for ``:4``).

    Table 4 (``research.rules.names``) and ``benchmarks/studies/flow_rules.py --rules`` name schedules this way.

    Returns:
        ``(rule, refinement)``: the schedule's rule and its :class:`Refinement`, or ``None``.

    Raises:
        SDMInputError: naming ``rule`` for an unknown rule, the schedule for a malformed pass count.
    """
    if not isinstance(name, str):
        raise SDMInputError(f"a schedule is a rule name or 'RULE+REFINE:E', got {name!r}")
    rule, plus, refined = name.partition("+")
    RULES.resolve(rule)
    if not plus:
        return rule, None
    refine, colon, passes = refined.partition(":")
    if colon and not (passes.isdigit() and passes[0] != "0"):
        raise SDMInputError(f"schedule {name!r}: the passes after ':' must be a positive integer, got {passes!r}")
    return rule, Refinement(refine, int(passes) if colon else Refinement.passes)


def refine_seed(seed: int) -> int:
    """The seed of the refinement passes' shuffling of a run seeded ``seed`` (a hash, stable across platforms)."""
    return int(np.random.SeedSequence([int(seed), 20]).generate_state(1, dtype=np.uint32)[0])

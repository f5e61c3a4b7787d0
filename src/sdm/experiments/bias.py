"""Where a gradient rule's flow vanishes: the flow at the true shift, per noise level and zoom, for ``(a, b)``
(:func:`rule_bias`, :func:`flow_at_true_shift`) and for the depth ``c`` (:func:`depth_bias`)."""
from __future__ import annotations

from typing import Sequence

import numpy as np
import pandas as pd
import torch

from ..batch import ConfigurationSet
from ..camera import Camera
from ..depth import depth_flow, depth_targets
from ..mapping import SpatialDomainMapping
from ..sky import SKY_SHIFT, shift_vector
from ..train import parse_schedule
from .runs import noisy_targets, run_seed


def flow_at_true_shift(train_set: ConfigurationSet, noise_levels: Sequence[int], seed: int, s: int = 4,
                       shift: Sequence[float] = SKY_SHIFT, camera: Camera | None = None,
                       batch_size: int = 64, rule: str = "paper", zooms: Sequence[int] | None = None,
                       at: Sequence[float] | None = None) -> pd.DataFrame:
    """The dynamic gradient flow *at* theta*, on each noise level's training targets (run 0's draw).

    Without noise theta* is a fixed point (the flow vanishes at every zoom level). With noisy
    targets it need not be: a non-zero mean flow at theta* is a pull that SGD follows past
    theta*, i.e. a bias of the noisy estimates, measured here instead of guessed.

    ``rule`` names the gradient rule measured (:data:`sdm.FLOW_RULES`, default the paper's); ``zooms`` the
    loss levels measured (default ``s .. 0``); ``at`` another theta to measure at (default theta* itself).

    Returns:
        One row per (noise level, zoom): ``noise_level, zoom, flow_a, flow_b`` (summed flow per
        training configuration; negative values push theta~ up) and ``unmatched`` (share of
        the points entering the zoom level that land on the grid in a block the target leaves empty).
    """
    camera = camera or train_set.camera
    theta = shift_vector(shift if at is None else at, train_set.points)
    rows = []
    for noise_level in noise_levels:
        noisy = train_set.with_targets(noisy_targets(train_set.targets, noise_level, run_seed(seed, noise_level, 0)))
        for zoom in (range(s, -1, -1) if zooms is None else zooms):
            layer = SpatialDomainMapping(camera, s=s, zoom=zoom, rule=rule)
            total = torch.zeros(2, dtype=torch.float64, device=train_set.device)
            entered = unmatched = 0
            for _, batch in noisy.batches(batch_size):
                result = layer(batch.points + theta, batch.pixels, batch.targets, batch.config, batch.rank).result
                total += result.flow.sum(0)
                entered += int(result.entered.sum())
                unmatched += int(result.missed.sum())
            rows.append({"noise_level": int(noise_level), "zoom": zoom, "flow_a": float(total[0]) / len(noisy),
                         "flow_b": float(total[1]) / len(noisy), "unmatched": unmatched / max(entered, 1)})
    return pd.DataFrame.from_records(rows, columns=["noise_level", "zoom", "flow_a", "flow_b", "unmatched"])


def rule_bias(train_set: ConfigurationSet, schedule: str, noise_levels: Sequence[int], seed: int, s: int = 4,
              shift: Sequence[float] = SKY_SHIFT, camera: Camera | None = None, step: float = 1e-3) -> pd.DataFrame:
    """Where a rule's SGD settles, predicted from two measurements at the last level (zoom 0): the flow's
    bias at theta* under noise and its stiffness near theta* without noise.

    ``schedule`` may name a bare rule or a schedule (:func:`sdm.train.parse_schedule`): its last rule (the refinement's) is
    measured, the one whose fixed point the runs end at.

    SGD stops moving on average where the mean flow vanishes. Near theta* the flow per configuration is
    about ``bias + stiffness * (theta - theta*)`` per axis, so it vanishes ``-bias / stiffness`` from theta*.
    ``bias`` is :func:`flow_at_true_shift` at zoom 0 (run 0's noise draw of each level); ``stiffness`` the
    flow's central difference over ``theta* +- step`` per axis on the same draw (flow per configuration per
    metre). A measurement of where the rule's fixed point lies, not of SGD's scatter around it.

    Returns:
        One row per level: ``noise_level, bias_a, bias_b`` (flow per configuration), ``stiffness_a, stiffness_b``
        (per metre), ``offset_a, offset_b`` (metres, ``-bias / stiffness``) and ``predicted_m`` (their norm).
    """
    first, refine = parse_schedule(schedule)
    rule = refine.rule if refine is not None else first
    camera = camera or train_set.camera
    rows = []
    for noise_level in noise_levels:
        bias = flow_at_true_shift(train_set, [noise_level], seed, s, shift, camera, rule=rule, zooms=[0])
        row = {"noise_level": int(noise_level)}
        for axis, name in enumerate("ab"):
            ends = []
            for sign in (1.0, -1.0):
                at = [float(v) for v in shift]
                at[axis] += sign * step
                ends.append(float(flow_at_true_shift(train_set, [noise_level], seed, s, shift, camera, rule=rule, zooms=[0],
                                                     at=at)[f"flow_{name}"].iloc[0]))
            stiffness = (ends[0] - ends[1]) / (2 * step)
            row[f"bias_{name}"] = float(bias[f"flow_{name}"].iloc[0])
            row[f"stiffness_{name}"] = stiffness
            row[f"offset_{name}"] = -row[f"bias_{name}"] / stiffness if stiffness else float("nan")
        rows.append(row | {"predicted_m": float(np.hypot(row["offset_a"], row["offset_b"]))})
    return pd.DataFrame.from_records(rows, columns=["noise_level", "bias_a", "stiffness_a", "offset_a", "bias_b",
                                                    "stiffness_b", "offset_b", "predicted_m"])


#: Columns of :func:`depth_bias`.
DEPTH_BIAS_COLUMNS = ["c_true", "noise_level", "zoom", "flow_c", "stiffness_c", "offset_c", "edge_share",
                      "unmatched_edge", "unmatched_inside"]


def depth_bias(train_set: ConfigurationSet, c: float, noise_levels: Sequence[int], seed: int, schedule: str = "paper",
               s: int = 4, zooms: Sequence[int] | None = None, shift: Sequence[float] = SKY_SHIFT,
               camera: Camera | None = None, step: float = 1e-2, batch_size: int = 64) -> pd.DataFrame:
    """Table 5's bias of ``c``, measured at theta* = ``(a*, b*, c*)``: the depth flow there under noise, where
    it comes from, and where SGD on ``c`` alone would settle.

    The targets are :func:`depth_noise_runs`' (the points moved by theta*, then run 0's noise draw of each
    level, :func:`run_seed` ``(seed, noise_level, 0)``). At each loss level ``zoom`` the points sit at theta* and the
    layer's flow gives each point its depth flow (:func:`sdm.depth.depth_flow`; SGD moves ``c`` against it:
    a negative ``flow_c`` moves the estimate farther). ``stiffness_c`` is its central difference over
    ``c* +- step`` on the same targets, so ``offset_c = -flow_c / stiffness_c`` is where the mean flow on
    ``c`` vanishes with ``(a, b)`` held at theta*: a measurement of the fixed point, not of SGD's scatter.

    The *edge* points are those with a pixel among the 8 around theirs that holds no point of their
    configuration (the rim of every disc of ``E'``); ``edge_share`` is their part of ``flow_c``, and
    ``unmatched_edge`` / ``unmatched_inside`` the shares of the edge / other points entering the level that
    land in a block the noisy target leaves empty (the points that the rule pulls).

    Args:
        train_set: the training configurations (their points; their own targets are not used).
        c: ``c*``, metres. levels: noise levels. seed: the experiment's seed.
        schedule: the rule measured (a name of :data:`sdm.FLOW_RULES`; a schedule's last rule for a schedule).
        s: coarsest zoom level; zooms: the loss levels measured (default ``s .. 0``).
        shift: ``(a*, b*)``, metres. camera: default the set's. step: metres of ``c``.
        batch_size: configurations per layer call (memory only: the sums are the same).

    Returns:
        One row per (noise level, zoom), columns :data:`DEPTH_BIAS_COLUMNS`; ``flow_c`` per training
        configuration, ``stiffness_c`` per configuration per metre, ``offset_c`` in metres.
    """
    first, refine = parse_schedule(schedule)
    rule = refine.rule if refine is not None else first
    camera = camera or train_set.camera
    truth = (float(shift[0]), float(shift[1]), float(c))
    clean = depth_targets(train_set, truth, camera)
    height, width = camera.screen_shape
    edges = []  # each batch's (P,) edge points: they depend on the points only, not on the level or the zoom
    for _, batch in train_set.batches(batch_size):
        occupied = torch.zeros(int(batch.config.max()) + 1, height, width, dtype=torch.float32,
                               device=batch.points.device)
        occupied[batch.config, batch.pixels[:, 0], batch.pixels[:, 1]] = 1.0
        empty_near = torch.nn.functional.max_pool2d(1.0 - occupied[:, None], 3, 1, 1)[:, 0] > 0
        edges.append(empty_near[batch.config, batch.pixels[:, 0], batch.pixels[:, 1]])
    rows = []
    for noise_level in noise_levels:
        noisy = train_set.with_targets(noisy_targets(clean, noise_level, run_seed(seed, noise_level, 0)))
        for zoom in (range(s, -1, -1) if zooms is None else zooms):
            layer = SpatialDomainMapping(camera, s=s, zoom=zoom, rule=rule)
            # [flow_c at c*, at c* + step, at c* - step, edge part at c*, (edge, inside) entered and unmatched]
            sums = np.zeros(8)
            for (_, batch), edge in zip(noisy.batches(batch_size), edges, strict=True):
                for index, dc in enumerate((0.0, step, -step)):
                    points = batch.points + shift_vector((truth[0], truth[1], truth[2] + dc), batch.points)
                    result = layer(points, batch.pixels, batch.targets, batch.config, batch.rank).result
                    pull = depth_flow(points, result.flow)
                    sums[index] += float(pull.sum())
                    if index == 0:
                        sums[3] += float(pull[edge].sum())
                        for part, where in enumerate((edge, ~edge)):
                            sums[4 + 2 * part] += float(result.entered[where].sum())
                            sums[5 + 2 * part] += float(result.missed[where].sum())
            n_configs = len(noisy)
            stiffness = (sums[1] - sums[2]) / (2 * step) / n_configs
            flow_c = sums[0] / n_configs
            rows.append({"c_true": truth[2], "noise_level": int(noise_level), "zoom": int(zoom), "flow_c": flow_c,
                         "stiffness_c": stiffness, "offset_c": -flow_c / stiffness if stiffness else float("nan"),
                         "edge_share": sums[3] / sums[0] if sums[0] else float("nan"),
                         "unmatched_edge": sums[5] / max(sums[4], 1), "unmatched_inside": sums[7] / max(sums[6], 1)})
    return pd.DataFrame.from_records(rows, columns=DEPTH_BIAS_COLUMNS)

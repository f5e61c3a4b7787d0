"""Table 7 at test time: every trained network alone and with k SDM steps, beside the searches that use no network,
and where an SDM rule's flow vanishes on the test set."""
from __future__ import annotations

import math
import time

import numpy as np
import pandas as pd
import torch

from .. import sharing as S
from ..baselines.rows import fit_configurations
from ..mapping.layer import SpatialDomainMapping
from ..objects import prior_totals, sdm_rows, shared_start
from ..sky import shift_vector
from ..train import TrainSettings, rates_per_point, train_runs
from .data import ShiftSet
from .model import ShiftNet
from .training import distances, predict

def refine(test: ShiftSet, theta0: torch.Tensor, settings) -> torch.Tensor:
    """SDM per configuration from ``theta0``: one row per configuration, ``settings``' levels ``s..0``.

    Every configuration's own row moves by its flow (:func:`sdm.train.train_runs` with
    :func:`sdm.sharing.per_configuration`'s index, every row at ``settings.lr`` per point at the mean points
    per row, :func:`sdm.train.rates_per_point`). A row gets ``k = (s + 1) n_epoch`` steps when the batch size
    divides the set. The coarse levels matter: a level-0 layer alone pulls only the points next to their
    target's pixels, and from a network's estimate a few pixels off it drifts (measured on the dev set).

    Returns:
        ``(N, 2)`` float64 metres.
    """

    sharing = S.per_configuration(test.data)
    history = train_runs(test.data, [test.data.targets], [settings], theta0=[theta0.detach().double()],
                         param_index=sharing.param_index, row_rate=rates_per_point(sharing.param_index))
    return history.theta[-1, 0]


def refine_steps(settings) -> int:
    """``k``, the steps :func:`refine` gives each configuration: ``(s - zoom + 1) n_epoch``."""
    return (settings.s - settings.zoom + 1) * settings.n_epoch


#: Table 7's methods at test time besides the networks (per-configuration searches from scratch).
SEARCHES = ("cmaes", "sdm_zero")


def test_methods(test: ShiftSet, level: int, networks: dict[str, ShiftNet], refine_settings, objects_settings,
                 seed: int) -> pd.DataFrame:
    """Every Table 7 method on the test configurations at one noise level: one row per (method, configuration).

    Methods (``method`` column):

    * ``net:LOSS``: the network trained with ``LOSS``, one forward pass per configuration;
    * ``net+k:LOSS``: then ``k`` SDM steps per configuration from its output (:func:`refine`, :func:`refine_steps`);
    * ``cmaes``: CMA-ES per configuration on its exact pixel mismatch (:func:`sdm.baselines.rows.fit_configurations`),
      started from SDM's shared start, as in Table 6;
    * ``sdm_zero``: SDM per configuration from zero: the shared start, then one row per configuration with the
      recommended schedule (:func:`sdm.objects.sdm_rows`, Table 6's ``sdm_schedule``);
    * the do-nothing references: ``prior``, theta*'s mean for every configuration (the centre of the
      distribution the shifts are drawn from, :func:`sdm.objects.prior_totals`; no pixel looked at), and
      ``start``, the shared start that CMA-ES is given.

    ``cpu_s`` is each method's CPU (process) seconds per configuration: the forward passes (and the refinement)
    over the set divided by its size; a search's own seconds per configuration plus its share of the shared start.

    Args:
        test: the test configurations, every target at noise ``level``.
        networks: trained networks by loss name.
        refine_settings: :class:`sdm.train.TrainSettings` of the SDM steps after each network (rule, levels,
            epochs per level, rate per point, batch size, seed).
        objects_settings: :class:`sdm.objects.ObjectsSettings` (the shared start, the rows, the schedule, CMA-ES).
        seed: seeds the searches.
    """

    n_configs = len(test)
    frames = []

    def record(method: str, theta: torch.Tensor, cpu_s) -> None:
        gap = distances(theta, test.truth)
        cpu = torch.as_tensor(cpu_s, dtype=torch.float64).expand(n_configs)
        frames.append(pd.DataFrame({"level": int(level), "method": method, "config": np.arange(n_configs),
                                    "distance": gap.cpu().numpy(), "cpu_s": cpu.cpu().numpy()}))

    for loss, net in networks.items():
        began = time.process_time()
        theta = predict(net, test.data)
        forward = time.process_time() - began
        record(f"net:{loss}", theta, forward / n_configs)
        began = time.process_time()
        refined = refine(test, theta, refine_settings)
        record(f"net+k:{loss}", refined, (forward + time.process_time() - began) / n_configs)
    sharing = S.per_configuration(test.data)
    units = S.units(test.data, sharing.param_index, sharing.n_rows)
    targets = test.data.targets
    start = shared_start(test.data, targets, seed, objects_settings)
    record("prior", prior_totals(objects_settings.truth, n_configs), 0.0)
    record("start", start[0].expand(n_configs, 2), start[1] / n_configs)
    theta, _, seconds, _ = sdm_rows(test.data, targets, sharing, seed, objects_settings, objects_settings.schedule)
    record("sdm_zero", theta, seconds / n_configs)
    result = fit_configurations(test.data, units, objects_settings.cmaes, seed,
                                theta0=start[0].expand(len(units), 2).clone())
    record("cmaes", result.totals, result.seconds + start[1] / n_configs)
    return pd.concat(frames, ignore_index=True)


def refine_settings(refine: dict, seed: int):
    """The :class:`sdm.train.TrainSettings` of the k steps after the network (``research.network.refine``)."""

    return TrainSettings(lr=float(refine["lr"]), batch_size=int(refine["batch_size"]), flow=str(refine["flow"]),
                         s=int(refine["s"]), n_epoch=int(refine["n_epoch"]), zoom=0, seed=int(seed))


def flow_bias(test: ShiftSet, level: int, rule: str, s: int, step: float = 1e-3, batch_size: int = 64) -> dict:
    """Where a rule's flow vanishes on the test configurations, measured as :func:`sdm.experiments.rule_bias` does.

    At zoom 0 (chain from ``s``), each configuration's flow per point is evaluated at its own theta*_i (its *bias*)
    and at ``theta*_i +- step`` per axis (its *stiffness*, per metre). A network trained through the rule settles,
    on average, where the mean flow vanishes: about ``-mean bias / mean stiffness`` from theta* per axis.

    Returns:
        ``{"level", "rule", "bias_a", "bias_b", "stiffness_a", "stiffness_b", "offset_m"}``: the means over the
        configurations (flow per point; per point per metre) and the predicted offset's norm (metres).
    """
    layer = SpatialDomainMapping(test.data.camera, s=s, zoom=0, flow=rule)
    counts = test.data.counts.to(torch.float64).unsqueeze(1)

    def mean_flow(at: torch.Tensor) -> torch.Tensor:
        total = torch.zeros(len(test), 2, dtype=torch.float64, device=test.data.device)
        for first in range(0, len(test), batch_size):
            indices = torch.arange(first, min(first + batch_size, len(test)), device=test.data.device)
            batch = test.data.batch(indices)
            points = batch.points + shift_vector(at.index_select(0, indices).index_select(0, batch.config),
                                                 batch.points)
            out = layer(points, batch.pixels, batch.targets, batch.config, batch.rank)
            total.index_add_(0, indices.index_select(0, batch.config), out.result.flow.double())
        return (total / counts).mean(0)

    bias = mean_flow(test.truth)
    row = {"level": int(level), "rule": rule, "bias_a": float(bias[0]), "bias_b": float(bias[1])}
    offsets = []
    for axis, name in enumerate("ab"):
        move = torch.zeros(2, dtype=torch.float64)
        move[axis] = step
        stiffness = float((mean_flow(test.truth + move) - mean_flow(test.truth - move))[axis]) / (2 * step)
        row[f"stiffness_{name}"] = stiffness
        offsets.append(-row[f"bias_{name}"] / stiffness if stiffness else math.nan)
    return row | {"offset_m": math.hypot(*offsets)}

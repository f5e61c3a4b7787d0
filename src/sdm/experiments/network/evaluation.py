"""Table 7 at test time: every trained network alone and with k SDM steps, beside the searches that use no network
and doing nothing, and where each label-free loss's mean gradient vanishes on the test set."""
from __future__ import annotations

import math
import time

import numpy as np
import pandas as pd
import torch

from ... import sharing as S
from ..baselines.rows import fit_configurations
from ...errors import SDMInputError
from ..objects import prior_totals, sdm_rows, shared_start
from ...train import TrainSettings, rates_per_point, train_runs
from .data import ShiftSet
from .losses import SDM_RULES, BatchLoss, NetworkSettings
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
#: Table 7's do-nothing references: theta*'s mean, the training set's mean theta*, the searches' shared start.
NOTHING = ("prior", "train_mean", "start")
#: The ``run`` of a row no training run made (the searches and the references).
NO_RUN = -1


def test_methods(test: ShiftSet, noise_level: int, networks: dict[tuple[str, int], ShiftNet], refine_settings,
                 objects_settings, seed: int, train_mean: torch.Tensor | None = None) -> pd.DataFrame:
    """Every Table 7 method on the test configurations at one noise level: one row per (method, run, configuration).

    Methods (``method`` column; ``run``: the training run of a network, :data:`NO_RUN` for the others):

    * ``net:LOSS``: the network trained with ``LOSS`` in that run, one forward pass per configuration;
    * ``net+k:LOSS``: then ``k`` SDM steps per configuration from its output (:func:`refine`, :func:`refine_steps`);
    * ``cmaes``: CMA-ES per configuration on its exact pixel mismatch (:func:`sdm.experiments.baselines.rows.fit_configurations`),
      started from SDM's shared start, as in Table 6;
    * ``sdm_zero``: SDM per configuration from zero: the shared start, then one row per configuration with the
      recommended schedule (:func:`sdm.experiments.objects.sdm_rows`, Table 6's ``sdm_schedule``);
    * the do-nothing references (:data:`NOTHING`): ``prior``, theta*'s mean for every configuration (the centre of
      the distribution the shifts are drawn from, :func:`sdm.experiments.objects.prior_totals`; no pixel looked at);
      ``train_mean``, the training set's mean theta* for every configuration (what a network that ignores its
      input learns at best; only with ``train_mean``); ``start``, the shared start that CMA-ES is given.

    ``error_a``, ``error_b``: ``theta - theta*`` per axis, metres (their mean over the set is a method's bias);
    ``distance``: its norm. ``cpu_s`` is each method's CPU (process) seconds per configuration: the forward passes
    (and the refinement) over the set divided by its size; a search's own seconds per configuration plus its share
    of the shared start.

    Args:
        test: the test configurations, every target at noise ``noise_level``.
        networks: trained networks by (loss name, training run).
        refine_settings: :class:`sdm.train.TrainSettings` of the SDM steps after each network (rule, levels,
            epochs per level, rate per point, batch size, seed).
        objects_settings: :class:`sdm.experiments.objects.ObjectsSettings` (the shared start, the rows, the schedule, CMA-ES).
        seed: seeds the searches.
        train_mean: ``(2,)`` float64 metres, the training set's mean theta*.
    """
    n_configs = len(test)
    frames = []

    def record(method: str, theta: torch.Tensor, cpu_s, run: int = NO_RUN) -> None:
        error = (theta.double() - test.truth.double()).cpu()
        cpu = torch.as_tensor(cpu_s, dtype=torch.float64).expand(n_configs)
        frames.append(pd.DataFrame({"noise_level": int(noise_level), "method": method, "run": int(run),
                                    "config": np.arange(n_configs), "distance": distances(theta, test.truth).cpu(),
                                    "error_a": error[:, 0], "error_b": error[:, 1], "cpu_s": cpu.cpu().numpy()}))

    for (loss, run), net in networks.items():
        began = time.process_time()
        theta = predict(net, test.data)
        forward = time.process_time() - began
        record(f"net:{loss}", theta, forward / n_configs, run)
        began = time.process_time()
        refined = refine(test, theta, refine_settings)
        record(f"net+k:{loss}", refined, (forward + time.process_time() - began) / n_configs, run)
    sharing = S.per_configuration(test.data)
    units = S.units(test.data, sharing.param_index, sharing.n_rows)
    targets = test.data.targets
    start = shared_start(test.data, targets, seed, objects_settings)
    record("prior", prior_totals(objects_settings.truth, n_configs), 0.0)
    if train_mean is not None:
        record("train_mean", torch.as_tensor(train_mean, dtype=torch.float64).reshape(1, 2).expand(n_configs, 2), 0.0)
    record("start", start[0].expand(n_configs, 2), start[1] / n_configs)
    theta, _, seconds, _ = sdm_rows(test.data, targets, sharing, seed, objects_settings, objects_settings.schedule)
    record("sdm_zero", theta, seconds / n_configs)
    result = fit_configurations(test.data, units, objects_settings.cmaes, seed,
                                theta0=start[0].expand(len(units), 2).clone())
    record("cmaes", result.totals, result.seconds + start[1] / n_configs)
    return pd.concat(frames, ignore_index=True)


def refine_settings(refine: dict, seed: int):
    """The :class:`sdm.train.TrainSettings` of the k steps after the network (``research.network.refine``)."""
    return TrainSettings(lr=float(refine["lr"]), batch_size=int(refine["batch_size"]), rule=str(refine["rule"]),
                         s=int(refine["s"]), n_epoch=int(refine["n_epoch"]), zoom=0, seed=int(seed))


#: The losses whose mean gradient's zero :func:`loss_bias` measures: SDM's flow (per point) and the silhouette's
#: gradient (per image), each a gradient of one configuration's own term. (Chamfer's mean runs over the batch's
#: pairs, supervised regression's vanishes at theta*.)
BIAS_LOSSES = ("sdm_paper", "sdm_closed_centred_r1", "silhouette")


def loss_bias(test: ShiftSet, noise_level: int, kind: str, settings: NetworkSettings, step: float = 1e-3,
              batch_size: int = 64) -> dict:
    """Where a training loss's mean gradient vanishes on the test configurations, as :func:`sdm.experiments.rule_bias`
    measures it for the shared shift.

    At zoom 0, where every training ends (:func:`sdm.experiments.network.epoch_zooms`), each configuration's gradient
    through :class:`sdm.experiments.network.BatchLoss` (SDM: the flow per point; the silhouette: its image loss's gradient) is
    evaluated at its own theta*_i (its *bias*) and at ``theta*_i +- step`` per axis (its *stiffness*, per metre). A
    network trained with the loss settles, on average, where the mean gradient vanishes: about
    ``-mean bias / mean stiffness`` from theta* per axis.

    Args:
        test: the test configurations at noise ``noise_level``.
        kind: one of :data:`BIAS_LOSSES`.
        settings: the training's settings (the SDM chain's ``s``, the silhouette's ``sigma``).

    Returns:
        ``{"noise_level", "loss", "bias_a", "bias_b", "stiffness_a", "stiffness_b", "offset_m"}``: the means over the
        configurations (gradient; its change per metre) and the predicted offset's norm (metres).
    """
    if kind not in BIAS_LOSSES:
        raise SDMInputError(f"loss must be one of {list(BIAS_LOSSES)}, got {kind!r}")
    loss_of = BatchLoss(kind, test, settings, torch.Generator().manual_seed(int(settings.seed)))
    device = test.data.device

    def mean_gradient(at: torch.Tensor) -> torch.Tensor:
        total = torch.zeros(len(test), 2, dtype=torch.float64, device=device)
        for first in range(0, len(test), batch_size):
            indices = torch.arange(first, min(first + batch_size, len(test)), device=device)
            theta = at.index_select(0, indices).clone().requires_grad_(True)
            (gradient,) = torch.autograd.grad(loss_of(theta, indices, 0), theta)
            # SDM's loss gives each configuration its flow per point; a mean over the batch gives 1/B of its own term
            total[indices] = gradient.double() * (1 if kind in SDM_RULES else len(indices))
        return total.mean(0)

    truth = test.truth.to(torch.float64)
    bias = mean_gradient(truth)
    row = {"noise_level": int(noise_level), "loss": kind, "bias_a": float(bias[0]), "bias_b": float(bias[1])}
    offsets = []
    for axis, name in enumerate("ab"):
        move = torch.zeros(2, dtype=torch.float64, device=device)
        move[axis] = step
        stiffness = float((mean_gradient(truth + move) - mean_gradient(truth - move))[axis]) / (2 * step)
        row[f"stiffness_{name}"] = stiffness
        offsets.append(-row[f"bias_{name}"] / stiffness if stiffness else math.nan)
    return row | {"offset_m": math.hypot(*offsets)}

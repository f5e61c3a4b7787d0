"""Table 7's training loop: a fresh :class:`ShiftNet` trained with one loss, seeded and deterministic, with its dev
learning curve."""
from __future__ import annotations

import os
import time
from contextlib import contextmanager
from dataclasses import dataclass

import pandas as pd
import torch
from tqdm.std import tqdm  # plain text: renders in notebooks without ipywidgets

from ...batch import ConfigurationSet
from ...errors import SDMInputError
from ...sharing import TruthDistribution
from .data import ShiftSet, network_images
from .losses import BatchLoss, NetworkSettings, epoch_zooms
from .model import ShiftNet

@contextmanager
def deterministic():
    """Torch's deterministic algorithms for the block (restored after).

    On a GPU, cuBLAS is deterministic only with a fixed workspace: ``CUBLAS_WORKSPACE_CONFIG`` is set to
    ``:4096:8`` unless the environment gives one (torch refuses a cuBLAS call in this mode without it).
    """
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    was = torch.are_deterministic_algorithms_enabled()
    torch.use_deterministic_algorithms(True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(was)


def predict(net: ShiftNet, data: ConfigurationSet, batch_size: int = 64) -> torch.Tensor:
    """``(N, 2)`` float64 the network's shift of every configuration (one forward pass each, no gradient)."""
    was = net.training
    net.eval()
    with torch.no_grad():
        out = [net(network_images(data, torch.arange(first, min(first + batch_size, len(data)), device=data.device)))
               for first in range(0, len(data), batch_size)]
    net.train(was)
    return torch.cat(out)


def distances(theta: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """``(N,)`` float64 Euclidean distance of each configuration's shift to theta*, metres."""
    return torch.linalg.vector_norm(theta.double() - truth.double(), dim=1)


@dataclass
class TrainedNetwork:
    """A trained network and its record.

    Attributes:
        net: the network (eval mode).
        curve: one row per epoch: ``loss`` (the training loss's name), ``epoch`` (1-based), ``zoom``
            (zoom level of the epoch), ``train_loss`` (mean over its steps), ``dev_mean_m``, ``dev_median_m``,
            ``train_cpu_s`` (the training's CPU seconds up to the epoch's end).
        seconds: the training's CPU (process) seconds, dev evaluations excluded.
    """

    net: ShiftNet
    curve: pd.DataFrame
    seconds: float


def train_network(kind: str, train: ShiftSet, dev: ShiftSet, settings: NetworkSettings,
                  progress: bool = False, prior: TruthDistribution = TruthDistribution()) -> TrainedNetwork:
    """Train a fresh :class:`ShiftNet` (weights from ``settings.seed``; outputs in the units of ``prior``, theta*'s
    distribution: its centre and ``camera_sd``) with loss ``kind``, deterministically.

    Each epoch visits the training set in a shuffled order (one generator seeded ``settings.seed``), its first
    ``per_epoch`` configurations where that is set, in batches of ``batch_size`` (the last incomplete one dropped);
    after each, the dev set's distances are recorded.
    """
    if len(train) < settings.batch_size:
        raise SDMInputError(f"train: {len(train)} configurations, fewer than one batch of {settings.batch_size}")
    zooms = epoch_zooms(settings.epochs, settings.s)
    steps_per_epoch = min(len(train), settings.per_epoch or len(train)) // settings.batch_size
    with deterministic():
        torch.manual_seed(settings.seed)
        net = ShiftNet(train.data.camera.screen_shape, centre=prior.centre, scale=prior.camera_sd)
        net = net.to(train.data.device)
        generator = torch.Generator().manual_seed(settings.seed)
        loss_of = BatchLoss(kind, train, settings, generator)
        optimiser = torch.optim.Adam(net.parameters(), lr=settings.rate(kind))
        schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, settings.epochs * steps_per_epoch)
        rows, seconds = [], 0.0
        bar = _progress(settings.epochs * steps_per_epoch, f"training ({kind})", progress)
        for epoch, zoom in enumerate(zooms, start=1):
            began = time.process_time()
            order = torch.randperm(len(train), generator=generator).to(train.data.device)
            total = 0.0
            for step in range(steps_per_epoch):
                indices = order[step * settings.batch_size:(step + 1) * settings.batch_size]
                theta = net(network_images(train.data, indices))
                loss = loss_of(theta, indices, zoom)
                optimiser.zero_grad(set_to_none=True)
                loss.backward()
                optimiser.step()
                schedule.step()
                total += float(loss.detach())
                bar.update()
            seconds += time.process_time() - began
            gap = distances(predict(net, dev.data), dev.truth)
            rows.append({"loss": kind, "epoch": epoch, "zoom": zoom, "train_loss": total / steps_per_epoch,
                         "dev_mean_m": float(gap.mean()), "dev_median_m": float(gap.median()),
                         "train_cpu_s": seconds})
        bar.close()
    net.eval()
    return TrainedNetwork(net, pd.DataFrame(rows), seconds)


def _progress(total: int, description: str, show: bool):
    return tqdm(total=total, desc=description, disable=not show, leave=False)


def network_settings(train: dict, seed: int) -> NetworkSettings:
    """:class:`NetworkSettings` from the config's ``research.network.train`` values (``per_epoch`` optional: 0) and a
    training run's seed (:func:`sdm.experiments.network.data.training_seed`)."""
    return NetworkSettings(epochs=int(train["epochs"]), batch_size=int(train["batch_size"]),
                           per_epoch=int(train.get("per_epoch", 0)),
                           lr=(("default", float(train["lr"])),), s=int(train["s"]), sigma=float(train["sigma"]),
                           max_points=int(train["max_points"]), seed=int(seed))

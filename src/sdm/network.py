"""SDM inside a network: a CNN that reads a configuration's images and outputs its shift, trained without labels.

Each configuration ``i`` has its own shift ``theta*_i = (a, b)`` (metres), drawn as Table 6's "a shift per
configuration" (:class:`sdm.sharing.TruthDistribution`); its target ``L_i`` is rendered from it and gets
Table 2's noise. A small CNN (:class:`ShiftNet`) reads two ``H x W`` images of the configuration and
outputs ``theta_i``:

* channel 0: the target ``L_i`` (1 where active);
* channel 1: ``Q_i`` rendered at zero shift, as inverse depth ``DEPTH_SCALE / z`` of the nearest point in each
  pixel (0 where empty). A point at depth ``z`` moves ``f' a / z`` pixels for a shift ``a``: the inverse
  depth tells the network how far each pixel's point moves.

The losses it is trained with (:data:`LOSSES`), the same architecture, data, initialisation seed and epochs:

* ``sdm_paper``, ``sdm_recommended``: the SDM layer's loss on ``Q_i + theta_i`` against ``L_i``; its backward
  is the dynamic gradient flow, carried by autograd through ``theta_i`` into the weights. No labels. The zoom
  level goes from ``s`` to 0 over the epochs (:func:`epoch_levels`). The paper's rule, or the recommended
  rule ``closed_centred_r1``.
* ``silhouette``: the soft-silhouette image loss (:mod:`sdm.baselines.silhouette`), coarse to fine on the same
  levels. No labels.
* ``chamfer``: the two-way 2D Chamfer distance (:mod:`sdm.baselines.chamfer`). No labels.
* ``supervised``: the mean squared distance to ``theta*_i``: what labels buy.

Every optimiser is Adam at one learning rate with a cosine decay over the steps. Training mixes the noise
levels: each training (and dev) configuration carries one level, drawn with the split's seed, because a
network in use does not know the noise of the image it reads.

Tensors: points float64 metres on the set's device; images float32; ``theta`` float64 metres, ``(N, 2)``.
"""
from __future__ import annotations

import hashlib
import math
import os
import pickle
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import pandas as pd
import torch
from torch import nn

from . import sharing as S
from .batch import ConfigurationSet
from .baselines.chamfer import chamfer_2d
from .baselines.common import pad_rows, project_shifted
from .baselines.silhouette import image_losses, soft_silhouette
from .errors import SDMInputError
from .experiments import noisy_targets
from .mapping.layer import SpatialDomainMapping
from .sky import shift_vector
from .zoom import zoom_out

#: The training losses, in Table 7's row order.
LOSSES = ("sdm_paper", "sdm_recommended", "silhouette", "chamfer", "supervised")
#: The gradient rule of each SDM loss.
SDM_RULES = {"sdm_paper": "paper", "sdm_recommended": "closed_centred_r1"}
#: Inverse-depth scale of the network's second channel, metres: ``DEPTH_SCALE / z`` is about 0.2-1 on the Sky set.
DEPTH_SCALE = 10.0


# -- data ---------------------------------------------------------------------------------------------


def split_three(n_total: int, sizes: Sequence[int], seed: int) -> dict[str, list[int]]:
    """``train``, ``dev`` and ``test`` index lists (each sorted): one seeded permutation of ``range(n_total)``, cut in
    order (:func:`sdm.experiments.split_indices`, its second part cut into dev and test).

    Raises:
        SDMInputError: naming ``sizes`` when they are not three positive integers summing to at most ``n_total``.
    """
    if len(sizes) != 3 or any(isinstance(v, bool) or int(v) != v or v < 1 for v in sizes):
        raise SDMInputError(f"sizes must be three positive integers (train, dev, test), got {list(sizes)!r}")
    if sum(sizes) > n_total:
        raise SDMInputError(f"sizes {list(sizes)} ask for {sum(sizes)} configurations; the set has {n_total}")
    from .experiments import split_indices

    train, dev, test = (int(size) for size in sizes)
    chosen = split_indices(n_total, train, dev + test, seed)  # the split stage's permutation, its rest cut in two
    return {"train": sorted(chosen["train"]), "dev": sorted(chosen["dev"][:dev]), "test": sorted(chosen["dev"][dev:])}


@dataclass(frozen=True)
class ShiftSet:
    """Configurations with a shift each, and their targets.

    Attributes:
        data: the configurations (points ``Q``); its targets are the rendered, noisy ``L`` (``(N, H, W)`` bool).
        truth: ``(N, 2)`` float64 ``theta*`` per configuration, metres.
        levels: ``(N,)`` int64 the noise level of each configuration's target.
    """

    data: ConfigurationSet
    truth: torch.Tensor
    levels: torch.Tensor

    def __len__(self) -> int:
        return len(self.data)

    def subset(self, indices: Sequence[int]) -> "ShiftSet":
        """Configurations ``indices`` (integers in ``[0, N)``, in that order), with their shifts and noise levels."""
        chosen = self.data.check_indices(indices).cpu()
        return ShiftSet(self.data.subset(chosen), self.truth[chosen.to(self.truth.device)], self.levels[chosen])


def shift_set(data: ConfigurationSet, seed: int, levels: Sequence[int] | torch.Tensor,
              truth: S.TruthDistribution = S.TruthDistribution()) -> ShiftSet:
    """Draw a shift per configuration (``seed``), render the targets, and add each configuration's noise level.

    Args:
        data: configurations, each with points (an empty one has no shift to learn: refused).
        seed: draws theta* (:func:`sdm.sharing.draw_truth`) and the noise (level ``n``'s configurations get one
            draw of :func:`sdm.experiments.noisy_targets` seeded ``seed + 1 + n``).
        levels: ``(N,)`` the noise level of each configuration (e.g. :func:`mixed_levels`).
        truth: the distribution of theta*.
    """
    if bool((data.counts == 0).any()):
        raise SDMInputError(f"data: configuration {int((data.counts == 0).nonzero()[0])} is empty (no points): "
                            "it has no shift to learn")
    levels = torch.as_tensor(levels, dtype=torch.int64).cpu()
    if levels.shape != (len(data),):
        raise SDMInputError(f"levels must hold one noise level per configuration ({len(data)}), "
                            f"got shape {tuple(levels.shape)}")
    sharing = S.per_configuration(data)
    theta = S.draw_truth(sharing, seed, truth)
    targets = S.render_targets(data, theta, sharing.param_index)
    for level in sorted(set(levels.tolist())):
        if level:
            chosen = (levels == level).nonzero().squeeze(1).to(targets.device)
            targets[chosen] = noisy_targets(targets.index_select(0, chosen), level, seed + 1 + level)
    return ShiftSet(data.with_targets(targets), theta, levels)


def mixed_levels(n_configs: int, levels: Sequence[int], seed: int) -> torch.Tensor:
    """``(n_configs,)`` int64: each configuration's noise level, uniform over ``levels``, drawn from ``seed``."""
    choice = torch.randint(len(levels), (n_configs,), generator=torch.Generator().manual_seed(int(seed)))
    return torch.as_tensor(list(levels), dtype=torch.int64)[choice]


#: The parts of a split, in the order their seeds are derived.
PARTS = ("train", "dev", "test")


def read_sets(sky: str | Path, sizes: Sequence[int], seed: int, levels: Sequence[int], camera_sd: float,
              parts: Sequence[str] = ("train", "dev"), test_level: int | None = None) -> dict[str, ShiftSet]:
    """The configurations of a Sky file split into train, dev and test (:func:`split_three`), each with its shifts.

    Part ``p`` draws theta* from ``run_seed(seed, PARTS.index(p), 0)``; train and dev mix ``levels``
    (:func:`mixed_levels`, seeded ``run_seed(seed, PARTS.index(p), 1)``); the test set takes every target at
    ``test_level``, so that its configurations keep their theta* at every level and only the noise differs.

    Raises:
        SDMInputError: naming ``test_level`` when the test part is asked for without it.
    """
    from .data import SkyFile
    from .experiments import run_seed

    truth = S.TruthDistribution(camera_sd=float(camera_sd))
    with SkyFile(sky) as file:
        split = split_three(len(file), sizes, seed)
        chosen = {part: [file[i] for i in split[part]] for part in parts}
        camera = file.camera
    sets = {}
    for part, configs in chosen.items():
        data = ConfigurationSet.from_configurations(configs, camera)
        index = PARTS.index(part)
        if part == "test":
            if test_level is None:
                raise SDMInputError("test_level: the test part needs its noise level")
            part_levels = torch.full((len(data),), int(test_level), dtype=torch.int64)
        else:
            part_levels = mixed_levels(len(data), levels, run_seed(seed, index, 1))
        sets[part] = shift_set(data, run_seed(seed, index, 0), part_levels, truth)
    return sets


def network_images(data: ConfigurationSet, indices: torch.Tensor) -> torch.Tensor:
    """The network's input for configurations ``indices``: ``(B, 2, H, W)`` float32 on the set's device.

    Channel 0 is the target ``L``; channel 1 is ``DEPTH_SCALE / z`` of the nearest point of ``Q`` in each pixel
    at zero shift (its own pixel; 0 where no point sits).
    """
    batch = data.batch(indices)
    height, width = data.camera.screen_shape
    flat = (batch.config * height + batch.pixels[:, 0]) * width + batch.pixels[:, 1]
    inverse = torch.zeros(len(indices) * height * width, dtype=torch.float64, device=data.device)
    inverse = inverse.scatter_reduce(0, flat, DEPTH_SCALE / batch.points[:, 2], reduce="amax")
    return torch.stack((batch.targets.float(), inverse.view(-1, height, width).float()), 1)


# -- the network ----------------------------------------------------------------------------------------


class ShiftNet(nn.Module):
    """A small CNN: ``(B, 2, H, W)`` images -> ``(B, 2)`` shift ``(a, b)`` in metres (float64).

    Five convolutions of stride 2 (8, 16, 32, 32, 32 channels; the first 5 x 5, the others 3 x 3), each
    followed by a ReLU, take a 128 x 256 screen to a 4 x 8 grid; the grid is flattened (positions matter: a
    shift moves the pixels) and two linear layers (``hidden`` units) give the shift. About 0.29 million
    parameters for a 128 x 256 screen, most in the first linear layer; the narrow convolutions keep a step
    cheap on a CPU. Plain ``torch.nn``.

    Args:
        screen: ``(H, W)``, both divisible by 32.
        hidden: the hidden linear layer's width.
    """

    def __init__(self, screen: tuple[int, int] = (128, 256), hidden: int = 256) -> None:
        super().__init__()
        height, width = screen
        if height % 32 or width % 32 or height < 32 or width < 32:
            raise SDMInputError(f"screen must have both sides divisible by 32, got {screen!r}")
        widths = (2, 8, 16, 32, 32, 32)
        layers: list[nn.Module] = []
        for index, (fan_in, fan_out) in enumerate(zip(widths[:-1], widths[1:])):
            kernel = 5 if index == 0 else 3
            layers += [nn.Conv2d(fan_in, fan_out, kernel, stride=2, padding=kernel // 2), nn.ReLU()]
        self.screen = (int(height), int(width))
        self.features = nn.Sequential(*layers, nn.Flatten())
        self.head = nn.Sequential(nn.Linear(widths[-1] * (height // 32) * (width // 32), hidden), nn.ReLU(),
                                  nn.Linear(hidden, 2))

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """``(B, 2, H, W)`` float32 -> ``(B, 2)`` float64 metres."""
        if images.ndim != 4 or images.shape[1] != 2 or tuple(images.shape[2:]) != self.screen:
            raise SDMInputError(f"images must have shape (B, 2, {self.screen[0]}, {self.screen[1]}), "
                                f"got {tuple(images.shape)}")
        return self.head(self.features(images)).double()


def parameter_count(net: nn.Module) -> int:
    """The number of trainable parameters."""
    return sum(p.numel() for p in net.parameters() if p.requires_grad)


# -- the losses -----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class NetworkSettings:
    """How every network is trained.

    Attributes:
        epochs: passes over the training set.
        batch_size: configurations per step.
        lr: Adam's learning rate (cosine decay to 0 over the steps), per loss name; missing names use ``"default"``.
        s: the coarsest zoom level of the SDM and silhouette losses (:func:`epoch_levels`).
        sigma: the silhouette's Gaussian width, in blocks of the level.
        max_points: Chamfer's points (and target pixels) per configuration and step; 0 = all.
        seed: initialises the weights and draws the shuffles.
    """

    epochs: int = 10
    batch_size: int = 16
    lr: tuple[tuple[str, float], ...] = (("default", 1e-3),)
    s: int = 2
    sigma: float = 0.5
    max_points: int = 256
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("epochs", "batch_size"):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value < 1:
                raise SDMInputError(f"NetworkSettings.{name} must be a positive integer, got {value!r}")
        if isinstance(self.s, bool) or int(self.s) != self.s or self.s < 0:
            raise SDMInputError(f"NetworkSettings.s must be a non-negative integer, got {self.s!r}")
        rates = dict(self.lr)
        if "default" not in rates or any(not (math.isfinite(v) and v > 0) for v in rates.values()):
            raise SDMInputError(f"NetworkSettings.lr must give a positive 'default' rate, got {self.lr!r}")
        if not self.sigma > 0:
            raise SDMInputError(f"NetworkSettings.sigma must be positive, got {self.sigma!r}")

    def rate(self, loss: str) -> float:
        rates = dict(self.lr)
        return float(rates.get(loss, rates["default"]))


def epoch_levels(epochs: int, s: int) -> list[int]:
    """The zoom level of each epoch: one epoch at each coarse level ``s..1``, then level 0 for the rest.

    The coarse levels bring a fresh network's shifts within a few pixels of the targets; the shifts of single
    configurations differ by about a pixel, which only level 0 resolves, so the epochs go there. Measured on a
    dev set (3,000 training configurations, 8 epochs): ``s..0`` in equal runs left the SDM-trained network at
    the dev distance of a constant shift; two coarse epochs and six at level 0 took it to two thirds of it.
    With fewer epochs than levels, the finest ``epochs`` levels.
    """
    coarse = list(range(s, 0, -1))
    if epochs <= len(coarse):
        return (coarse + [0])[-epochs:]
    return coarse + [0] * (epochs - len(coarse))


class BatchLoss:
    """One training loss on a mini-batch: ``loss(theta (B, 2), indices (B,), level) -> scalar``.

    Args:
        kind: one of :data:`LOSSES`.
        train: the training configurations (targets, and ``truth`` for ``supervised`` only).
        settings: the silhouette's width and Chamfer's points per configuration.
        generator: draws Chamfer's subsamples.
    """

    def __init__(self, kind: str, train: ShiftSet, settings: NetworkSettings, generator: torch.Generator) -> None:
        if kind not in LOSSES:
            raise SDMInputError(f"loss must be one of {list(LOSSES)}, got {kind!r}")
        self.kind, self.train, self.settings, self.generator = kind, train, settings, generator
        data = train.data
        self.camera = data.camera
        if kind in SDM_RULES:
            self.layers = {level: SpatialDomainMapping(data.camera, s=settings.s, zoom=level, flow=SDM_RULES[kind])
                           for level in range(settings.s + 1)}
            self.pyramid = data.pyramid(settings.s)

    def __call__(self, theta: torch.Tensor, indices: torch.Tensor, level: int) -> torch.Tensor:
        data = self.train.data
        if theta.shape != (len(indices), 2):
            raise SDMInputError(f"theta must have shape ({len(indices)}, 2): one shift (a, b) per configuration of "
                                f"the batch, got {tuple(theta.shape)}")
        if self.kind == "supervised":
            return ((theta - self.train.truth.index_select(0, indices)) ** 2).sum(1).mean()
        batch = data.batch(indices)
        if self.kind in SDM_RULES:  # a mean pull per point: every configuration weighs alike, whatever its points
            counts = data.counts.index_select(0, indices).to(theta.dtype).unsqueeze(1)
            theta = theta.detach() + (theta - theta.detach()) / counts
        moves = shift_vector(theta.index_select(0, batch.config), batch.points)
        if self.kind in SDM_RULES:
            return self.layers[level](batch.points + moves, batch.pixels, self.pyramid[level].index_select(0, indices),
                                      batch.config, batch.rank, target_is_zoomed=True, validate=False).loss
        if self.kind == "silhouette":
            screen = self.camera.project(batch.points + moves, validate=False).float()
            silhouette = soft_silhouette(screen, batch.config, len(indices), level, self.settings.sigma,
                                         self.camera.screen_shape)
            return image_losses(silhouette, zoom_out(batch.targets, level)).mean()
        return self._chamfer(theta, indices, batch)

    def _chamfer(self, theta, indices, batch) -> torch.Tensor:
        rows, _ = self.train.data.rows(indices)
        counts = self.train.data.counts.index_select(0, indices)
        points, point_mask = self._subsample(*pad_rows(self.train.data.points.index_select(0, rows), counts,
                                                       torch.cumsum(counts, 0) - counts))
        active = batch.targets.nonzero()
        target_counts = torch.bincount(active[:, 0], minlength=len(indices))
        centres, centre_mask = self._subsample(*pad_rows(active[:, 1:].to(points.dtype) + 0.5, target_counts,
                                                         torch.cumsum(target_counts, 0) - target_counts))
        screen = project_shifted(torch.where(point_mask.unsqueeze(-1), points, torch.ones_like(points)),
                                 theta.unsqueeze(1), self.camera)
        distances = chamfer_2d(screen, point_mask, centres, centre_mask)
        return distances[torch.isfinite(distances)].mean()

    def _subsample(self, values: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """At most ``max_points`` real entries of each row of ``(B, W, C)`` padded ``values``, chosen at random
        (all when 0): ``(B, min(W, max_points), C)`` and its mask. The search then costs ``max_points^2`` per
        configuration, not the widest configuration's points times its target pixels."""
        k = self.settings.max_points
        if not k or mask.shape[1] <= k:
            return values, mask
        keys = torch.rand(mask.shape, generator=self.generator, dtype=torch.float64).to(mask.device)
        chosen = torch.where(mask, keys, torch.full_like(keys, -1.0)).topk(k, dim=1).indices
        return values.gather(1, chosen.unsqueeze(-1).expand(-1, -1, values.shape[-1])), mask.gather(1, chosen)


# -- training ---------------------------------------------------------------------------------------------


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
        curve: one row per epoch: ``loss`` (the training loss's name), ``epoch`` (1-based), ``level``
            (zoom level of the epoch), ``train_loss`` (mean over its steps), ``dev_mean_m``, ``dev_median_m``,
            ``train_cpu_s`` (the training's CPU seconds up to the epoch's end).
        seconds: the training's CPU (process) seconds, dev evaluations excluded.
    """

    net: ShiftNet
    curve: pd.DataFrame
    seconds: float


def train_network(kind: str, train: ShiftSet, dev: ShiftSet, settings: NetworkSettings,
                  progress: bool = False) -> TrainedNetwork:
    """Train a fresh :class:`ShiftNet` (weights from ``settings.seed``) with loss ``kind``, deterministically.

    Each epoch visits the training set in a shuffled order (one generator seeded ``settings.seed``) in batches
    of ``batch_size`` (the last incomplete one dropped); after each, the dev set's distances are recorded.
    """
    if len(train) < settings.batch_size:
        raise SDMInputError(f"train: {len(train)} configurations, fewer than one batch of {settings.batch_size}")
    levels = epoch_levels(settings.epochs, settings.s)
    steps_per_epoch = len(train) // settings.batch_size
    with deterministic():
        torch.manual_seed(settings.seed)
        net = ShiftNet(train.data.camera.screen_shape).to(train.data.device)
        generator = torch.Generator().manual_seed(settings.seed)
        loss_of = BatchLoss(kind, train, settings, generator)
        optimiser = torch.optim.Adam(net.parameters(), lr=settings.rate(kind))
        schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, settings.epochs * steps_per_epoch)
        rows, seconds = [], 0.0
        bar = _progress(settings.epochs * steps_per_epoch, f"training ({kind})", progress)
        for epoch, level in enumerate(levels, start=1):
            began = time.process_time()
            order = torch.randperm(len(train), generator=generator).to(train.data.device)
            total = 0.0
            for step in range(steps_per_epoch):
                indices = order[step * settings.batch_size:(step + 1) * settings.batch_size]
                theta = net(network_images(train.data, indices))
                loss = loss_of(theta, indices, level)
                optimiser.zero_grad(set_to_none=True)
                loss.backward()
                optimiser.step()
                schedule.step()
                total += float(loss.detach())
                bar.update()
            seconds += time.process_time() - began
            gap = distances(predict(net, dev.data), dev.truth)
            rows.append({"loss": kind, "epoch": epoch, "level": level, "train_loss": total / steps_per_epoch,
                         "dev_mean_m": float(gap.mean()), "dev_median_m": float(gap.median()),
                         "train_cpu_s": seconds})
        bar.close()
    net.eval()
    return TrainedNetwork(net, pd.DataFrame(rows), seconds)


def _progress(total: int, description: str, show: bool):
    from tqdm.std import tqdm  # plain text: renders in notebooks without ipywidgets

    return tqdm(total=total, desc=description, disable=not show, leave=False)


# -- test time ----------------------------------------------------------------------------------------------


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
    from .train import rates_per_point, train_runs

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
    from .baselines.rows import fit_configurations
    from .objects import prior_totals, sdm_rows, shared_start

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


# -- settings and weights from the workflow's values ------------------------------------------------------------


def network_settings(train: dict, seed: int) -> NetworkSettings:
    """:class:`NetworkSettings` from the config's ``research.network.train`` values and its seed."""
    return NetworkSettings(epochs=int(train["epochs"]), batch_size=int(train["batch_size"]),
                           lr=(("default", float(train["lr"])),), s=int(train["s"]), sigma=float(train["sigma"]),
                           max_points=int(train["max_points"]), seed=int(seed))


def refine_settings(refine: dict, seed: int):
    """The :class:`sdm.train.TrainSettings` of the k steps after the network (``research.network.refine``)."""
    from .train import TrainSettings

    return TrainSettings(lr=float(refine["lr"]), batch_size=int(refine["batch_size"]), flow=str(refine["flow"]),
                         s=int(refine["s"]), n_epoch=int(refine["n_epoch"]), zoom=0, seed=int(seed))


def save_weights(net: ShiftNet, path: str | Path) -> Path:
    """Write ``net``'s state_dict to ``path`` atomically (a temporary file renamed), readable by others, with the
    SHA-256 of its parameters (:func:`weights_digest`) that :func:`load_weights` checks."""
    from .io import write_atomic

    state = net.state_dict()
    saved = {"screen": list(net.screen), "state": state, "sha256": weights_digest(state)}
    return write_atomic(path, lambda temporary: torch.save(saved, temporary))


def weights_digest(state: dict) -> str:
    """The SHA-256 (hex) of a state_dict: every entry's name, dtype, shape and bytes, in the dict's order."""
    digest = hashlib.sha256()
    for name, tensor in state.items():
        tensor = tensor.detach().to("cpu").contiguous()
        digest.update(f"{name}|{tensor.dtype}|{tuple(tensor.shape)}|".encode())
        digest.update(tensor.view(-1).view(torch.uint8).numpy().tobytes() if tensor.numel() else b"")
    return digest.hexdigest()


def load_weights(path: str | Path, screen: tuple[int, int]) -> ShiftNet:
    """A :class:`ShiftNet` for ``screen`` with the weights :func:`save_weights` wrote to ``path`` (eval mode).

    Raises:
        SDMInputError: naming the file when it is not such a file, its parameters do not match their SHA-256 (a
            damaged file) or hold a value that is not finite, or it was saved for another screen.
    """
    rerun = "rerun its network_train stage"
    try:
        saved = torch.load(path, map_location="cpu", weights_only=True)
        state, stored = saved["state"], saved.get("sha256")
        if stored != weights_digest(state):
            raise SDMInputError(f"{path}: its weights do not match their SHA-256 (damaged, or written without one); "
                                f"{rerun}")
        bad = [name for name, tensor in state.items()
               if tensor.is_floating_point() and not bool(tensor.isfinite().all())]
        if bad:
            raise SDMInputError(f"{path}: weights {bad[:3]} hold values that are not finite; {rerun}")
        net = ShiftNet(tuple(saved["screen"]))
        net.load_state_dict(state)
    except SDMInputError:
        raise
    except (OSError, RuntimeError, KeyError, TypeError, ValueError, AttributeError, EOFError,
            pickle.UnpicklingError) as error:
        raise SDMInputError(f"{path}: not a ShiftNet weights file ({error}); {rerun}") from None
    if net.screen != tuple(screen):
        raise SDMInputError(f"{path}: weights for a {net.screen} screen, the data's is {tuple(screen)}")
    return net.eval()


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

"""Table 7's training losses on a mini-batch (:class:`BatchLoss`), how every network is trained
(:class:`NetworkSettings`) and the zoom level of each epoch."""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..baselines.chamfer import chamfer_2d
from ..baselines.common import pad_rows, project_shifted
from ..baselines.silhouette import image_losses, soft_silhouette
from ...errors import SDMInputError
from ...mapping.layer import SpatialDomainMapping
from ...sky import shift_vector
from ...zoom import zoom_out
from .data import ShiftSet

#: The training losses, in Table 7's row order.
LOSSES = ("sdm_paper", "sdm_closed_centred_r1", "silhouette", "chamfer", "supervised")
#: The gradient rule of each SDM loss.
SDM_RULES = {"sdm_paper": "paper", "sdm_closed_centred_r1": "closed_centred_r1"}


@dataclass(frozen=True)
class NetworkSettings:
    """How every network is trained.

    Attributes:
        epochs: passes over the training set (each over ``per_epoch`` of its configurations).
        batch_size: configurations per step.
        per_epoch: configurations each epoch visits, a fresh shuffle's first ones; 0 = the whole training set.
        lr: Adam's learning rate (cosine decay to 0 over the steps), per loss name; missing names use ``"default"``.
        s: the coarsest zoom level of the SDM and silhouette losses (:func:`epoch_zooms`).
        sigma: the silhouette's Gaussian width, in blocks of the zoom level.
        max_points: Chamfer's points (and target pixels) per configuration and step; 0 = all.
        seed: initialises the weights and draws the shuffles (and Chamfer's subsamples).
    """

    epochs: int = 10
    batch_size: int = 16
    per_epoch: int = 0
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
        for name in ("per_epoch", "s"):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value < 0:
                raise SDMInputError(f"NetworkSettings.{name} must be a non-negative integer, got {value!r}")
        if 0 < self.per_epoch < self.batch_size:
            raise SDMInputError(f"NetworkSettings.per_epoch must be 0 (every configuration) or at least one batch "
                                f"({self.batch_size}), got {self.per_epoch!r}")
        rates = dict(self.lr)
        if "default" not in rates or any(not (math.isfinite(v) and v > 0) for v in rates.values()):
            raise SDMInputError(f"NetworkSettings.lr must give a positive 'default' rate, got {self.lr!r}")
        if not self.sigma > 0:
            raise SDMInputError(f"NetworkSettings.sigma must be positive, got {self.sigma!r}")

    def rate(self, loss: str) -> float:
        rates = dict(self.lr)
        return float(rates.get(loss, rates["default"]))


def epoch_zooms(epochs: int, s: int) -> list[int]:
    """The zoom level of each epoch: one epoch at each coarse level ``s..1``, then level 0 for the rest.

    The coarse zoom levels bring a fresh network's shifts within a few pixels of the targets; the shifts of single
    configurations differ by about a pixel, which only zoom 0 resolves, so the epochs go there. Measured on a
    dev set (3,000 training configurations, 8 epochs): ``s..0`` in equal runs left the SDM-trained network at
    the dev distance of a constant shift; two coarse epochs and six at zoom 0 took it to two thirds of it.
    With fewer epochs than zoom levels, the finest ``epochs`` ones.
    """
    coarse = list(range(s, 0, -1))
    if epochs <= len(coarse):
        return (coarse + [0])[-epochs:]
    return coarse + [0] * (epochs - len(coarse))


class BatchLoss:
    """One training loss on a mini-batch: ``loss(theta (B, 2), indices (B,), zoom) -> scalar``.

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
            self.layers = {zoom: SpatialDomainMapping(data.camera, s=settings.s, zoom=zoom, rule=SDM_RULES[kind])
                           for zoom in range(settings.s + 1)}
            self.pyramid = data.pyramid(settings.s)

    def __call__(self, theta: torch.Tensor, indices: torch.Tensor, zoom: int) -> torch.Tensor:
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
            return self.layers[zoom](batch.points + moves, batch.pixels, self.pyramid[zoom].index_select(0, indices),
                                      batch.config, batch.rank, target_is_zoomed=True, validate=False).loss
        if self.kind == "silhouette":
            screen = self.camera.project(batch.points + moves, validate=False).float()
            silhouette = soft_silhouette(screen, batch.config, len(indices), zoom, self.settings.sigma,
                                         self.camera.screen_shape)
            return image_losses(silhouette, zoom_out(batch.targets, zoom)).mean()
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

"""Accuracy and dev loss (paper, section 6.2; docs/method/paper.md, Training and evaluation)."""
from __future__ import annotations

import math

import torch

from .batch import ConfigurationSet
from .camera import Camera
from .mapping import SpatialDomainMapping
from .sky import SKY_SHIFT, shift_vector


def distance(theta, theta_star=SKY_SHIFT) -> float:
    """Euclidean distance ``||theta - theta*||`` in metres."""
    (a, b), (a_star, b_star) = (float(v) for v in theta), (float(v) for v in theta_star)
    return math.hypot(a - a_star, b - b_star)


def false_positive_pixels(
    data: ConfigurationSet, theta, s: int = 4, camera: Camera | None = None, batch_size: int = 64
) -> torch.Tensor:
    """Per configuration, the active pixels of ``L~`` (chain at zoom 0) that are not active in ``L``.

    Args:
        data: configurations and their targets.
        theta: the shift ``(a, b)`` in metres.
        s: coarsest zoom level of the chain.

    Returns:
        ``(N,)`` int64 counts, on the set's device.
    """
    camera = camera or data.camera
    layer = SpatialDomainMapping(camera, s=s, zoom=0)
    shift = shift_vector(theta, data.points)
    counts = torch.zeros(len(data), dtype=torch.int64, device=data.device)
    with torch.no_grad():
        for indices, batch in data.batches(batch_size):  # empty configurations render nothing: count 0
            out = layer(batch.points + shift, batch.pixels, batch.targets, batch.config, batch.rank)
            alive = out.result.alive
            pixels = out.result.out_pixels[alive]
            config = batch.config[alive]
            false = ~batch.targets[config, pixels[:, 0], pixels[:, 1]]
            counts[indices] = torch.bincount(config[false], minlength=len(indices))
    return counts


def dev_loss(data: ConfigurationSet, theta, s: int = 4, camera: Camera | None = None) -> float:
    """Table 1's dev loss: mean false-positive pixel count at zoom 0 over the configurations."""
    return float(false_positive_pixels(data, theta, s, camera).double().mean())

"""One-run references of the batched baseline helpers in :mod:`sdm.experiments.baselines.common`.

The library fits runs many at a time (``subsample_runs``, ``sampled_pairs``); these are what one run
draws alone, written plainly, so the tests can hold each batched run equal to them.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from sdm.experiments.baselines.common import active_pixels, on_screen, pad_points, pad_rows, project_shifted
from sdm.batch import ConfigurationSet
from sdm.camera import Camera


@dataclass(frozen=True)
class PaddedSet:
    """A :class:`~sdm.ConfigurationSet` as zero-padded per-configuration tensors.

    Attributes:
        points: ``(N, P, 3)`` float64 points ``Q`` in metres; padding rows are ``(0, 0, 1)`` (a
            point in front of the camera, so projecting it is finite) and masked out.
        point_mask: ``(N, P)`` bool, True for real points.
        centres: ``(N, T, 2)`` float64 centres ``(row + 0.5, col + 0.5)`` of the target's active
            pixels, screen pixels; padding rows are 0 and masked out.
        centre_mask: ``(N, T)`` bool, True for real target pixels.
        screen_shape: ``(H, W)``.
    """

    points: torch.Tensor
    point_mask: torch.Tensor
    centres: torch.Tensor
    centre_mask: torch.Tensor
    screen_shape: tuple[int, int]

    def __len__(self) -> int:
        return int(self.points.shape[0])


def pad_set(data: ConfigurationSet) -> PaddedSet:
    """Pack ``data``'s points and target pixels per configuration (see :class:`PaddedSet`)."""
    points, point_mask = pad_points(data)
    active, counts, offsets = active_pixels(data.targets)
    centres, centre_mask = pad_rows(active[:, 1:].to(data.points.dtype) + 0.5, counts, offsets)
    return PaddedSet(points, point_mask, centres, centre_mask, tuple(data.camera.screen_shape))


def subsample(mask: torch.Tensor, k: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """Pick up to ``k`` random real entries per row of a ``(B, P)`` mask, without replacement.

    Returns:
        ``(index, kept)``: ``(B, min(k, P))`` int64 column indices and bool, False where a row
        has fewer than ``k`` real entries (those indices point at padding).
    """
    if k <= 0 or k >= mask.shape[1]:
        index = torch.arange(mask.shape[1], device=mask.device).expand(mask.shape[0], -1)
        return index, mask
    keys = torch.rand(mask.shape, generator=generator, dtype=torch.float64).to(mask.device)
    keys = torch.where(mask, keys, torch.full_like(keys, -1.0))
    top, index = torch.topk(keys, k, dim=1)
    return index, top >= 0


def sampled_pair(padded: PaddedSet, configs: torch.Tensor, theta: torch.Tensor, camera: Camera, max_points: int,
                 generator: torch.Generator):
    """The two point sets the Chamfer and Sinkhorn losses compare, for a batch of configurations.

    Up to ``max_points`` points per configuration, shifted by ``theta`` and projected, and up to
    ``max_points`` target pixel centres, each drawn without replacement from ``generator`` (points first).

    Returns:
        ``(screen, kept, centres, target_kept)``: ``(B, n, 2)`` projected points (screen pixels, float),
        ``(B, n)`` bool (a real point that lands on screen), ``(B, m, 2)`` target centres, ``(B, m)`` bool.
    """
    index, kept = subsample(padded.point_mask[configs], max_points, generator)
    points = padded.points[configs].gather(1, index.unsqueeze(-1).expand(-1, -1, 3))
    screen = project_shifted(points, theta, camera)
    kept = kept & on_screen(screen, camera.screen_shape)
    target_index, target_kept = subsample(padded.centre_mask[configs], max_points, generator)
    centres = padded.centres[configs].gather(1, target_index.unsqueeze(-1).expand(-1, -1, 2))
    return screen, kept, centres, target_kept

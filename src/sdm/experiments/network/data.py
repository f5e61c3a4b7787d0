"""Table 7's data: the train, dev and test configurations, each with its own shift theta*_i and noisy target, and
the network's input images.

Tensors: points float64 metres on the set's device; images float32; ``theta`` float64 metres, ``(N, 2)``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import torch

from ... import sharing as S
from ...batch import ConfigurationSet
from ..data import SkyFile
from ...errors import SDMInputError
from ..runs import noisy_targets, run_seed, split_indices

#: Inverse-depth scale of the network's second channel, metres: ``DEPTH_SCALE / z`` is about 0.2-1 on the Sky set.
DEPTH_SCALE = 10.0


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
    noise_levels: torch.Tensor

    def __len__(self) -> int:
        return len(self.data)

    def subset(self, indices: Sequence[int]) -> "ShiftSet":
        """Configurations ``indices`` (integers in ``[0, N)``, in that order), with their shifts and noise levels."""
        chosen = self.data.check_indices(indices).cpu()
        return ShiftSet(self.data.subset(chosen), self.truth[chosen.to(self.truth.device)], self.noise_levels[chosen])


def shift_set(data: ConfigurationSet, seed: int, noise_levels: Sequence[int] | torch.Tensor,
              truth: S.TruthDistribution = S.TruthDistribution(), noise_seed: int | None = None) -> ShiftSet:
    """Draw a shift per configuration (``seed``), render the targets, and add each configuration's noise level.

    Args:
        data: configurations, each with points (an empty one has no shift to learn: refused).
        seed: draws theta* (:func:`sdm.sharing.draw_truth`) and, without ``noise_seed``, the noise.
        levels: ``(N,)`` the noise level of each configuration (e.g. :func:`mixed_noise_levels`).
        truth: the distribution of theta*.
        noise_seed: draws the noise (level ``n``'s configurations get one draw of
            :func:`sdm.experiments.noisy_targets` seeded ``noise_seed + 1 + n``); ``None``: ``seed``.
    """
    if bool((data.counts == 0).any()):
        raise SDMInputError(f"data: configuration {int((data.counts == 0).nonzero()[0])} is empty (no points): "
                            "it has no shift to learn")
    noise_levels = torch.as_tensor(noise_levels, dtype=torch.int64).cpu()
    if noise_levels.shape != (len(data),):
        raise SDMInputError(f"levels must hold one noise level per configuration ({len(data)}), "
                            f"got shape {tuple(noise_levels.shape)}")
    sharing = S.per_configuration(data)
    theta = S.draw_truth(sharing, seed, truth)
    targets = S.render_targets(data, theta, sharing.param_index)
    noise_seed = seed if noise_seed is None else int(noise_seed)
    for noise_level in sorted(set(noise_levels.tolist())):
        if noise_level:
            chosen = (noise_levels == noise_level).nonzero().squeeze(1).to(targets.device)
            targets[chosen] = noisy_targets(targets.index_select(0, chosen), noise_level, noise_seed + 1 + noise_level)
    return ShiftSet(data.with_targets(targets), theta, noise_levels)


def mixed_noise_levels(n_configs: int, noise_levels: Sequence[int], seed: int) -> torch.Tensor:
    """``(n_configs,)`` int64: each configuration's noise level, uniform over ``noise_levels``, drawn from ``seed``."""
    choice = torch.randint(len(noise_levels), (n_configs,), generator=torch.Generator().manual_seed(int(seed)))
    return torch.as_tensor(list(noise_levels), dtype=torch.int64)[choice]


#: The parts of a split, in the order their seeds are derived.
PARTS = ("train", "dev", "test")


def training_seed(seed: int, run: int) -> int:
    """The seed of training run ``run`` (0, 1, ...) of the split seeded ``seed``: a network's initial weights,
    its shuffles, Chamfer's subsamples and the training set's noise draws (:func:`read_sets`' ``train_noise``).
    The split, theta*, the noise levels and the dev and test sets keep ``seed``'s draws: every run of every loss
    sees the same configurations, so runs of the same number pair across losses."""
    return run_seed(seed, len(PARTS), run)


def read_sets(sky: str | Path, sizes: Sequence[int], seed: int, noise_levels: Sequence[int], camera_sd: float,
              parts: Sequence[str] = ("train", "dev"), test_level: int | None = None,
              train_noise: int | None = None) -> dict[str, ShiftSet]:
    """The configurations of a Sky file split into train, dev and test (:func:`split_three`), each with its shifts.

    Part ``p`` draws theta* from ``run_seed(seed, PARTS.index(p), 0)``; train and dev mix ``noise_levels``
    (:func:`mixed_noise_levels`, seeded ``run_seed(seed, PARTS.index(p), 1)``); the test set takes every target at
    ``test_level``, so that its configurations keep their theta* at every level and only the noise differs.
    Each part's noise is drawn from its theta* seed, the training part's from ``train_noise`` where given (a
    training run's own draws, :func:`training_seed`).

    Raises:
        SDMInputError: naming ``test_level`` when the test part is asked for without it.
    """

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
            part_levels = mixed_noise_levels(len(data), noise_levels, run_seed(seed, index, 1))
        noise = train_noise if part == "train" else None
        sets[part] = shift_set(data, run_seed(seed, index, 0), part_levels, truth, noise)
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

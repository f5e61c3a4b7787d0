"""Many Sky configurations packed as rows, for fast mini-batches.

A :class:`ConfigurationSet` stores the points of ``N`` configurations one after
another (CSR layout: configuration ``i`` owns rows ``offsets[i]:offsets[i+1]``)
with their targets, so a mini-batch is a cheap gather, not a Python loop.

A set lives on one device (that of its tensors, CPU when packed from
configurations); :meth:`ConfigurationSet.to` moves it. Every tensor a set
creates is created on its own device.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Sequence

import torch

from .camera import APOLLO_CAMERA_5, Camera
from .errors import SDMInputError
from .representation import priority_rank
from .sky import SkyConfiguration, pixel_centre_points
from .zoom import target_pyramid


@dataclass(frozen=True)
class PointBatch:
    """The points of a few configurations, ready for the SDM layer.

    Attributes:
        points: ``(P, 3)`` float64 points ``Q`` in metres (before the shift).
        pixels: ``(P, 2)`` int64 pixel ``(row, col)`` each point sits in.
        config: ``(P,)`` int64 batch-local configuration index in ``[0, n)``.
        rank: ``(P,)`` int64 ``rmin`` priority (depth, then position); lower wins.
        targets: ``(n, H, W)`` bool targets.
    """

    points: torch.Tensor
    pixels: torch.Tensor
    config: torch.Tensor
    rank: torch.Tensor
    targets: torch.Tensor

    @property
    def num_configs(self) -> int:
        return int(self.targets.shape[0])


class ConfigurationSet:
    """``N`` configurations, packed.

    All tensors live on one device, :attr:`device`.

    Attributes:
        points: ``(P, 3)`` float64 metres, all configurations' points ``Q``.
        pixels: ``(P, 2)`` int64 their pixels.
        offsets: ``(N + 1,)`` int64 row offsets.
        targets: ``(N, H, W)`` bool targets ``L``.
        rank: ``(P,)`` int64 ``rmin`` priority, comparable within a configuration.
        image_ids: ``N`` names of the source images.
        camera: the camera and screen.
        cars: ``(P,)`` int64 the car each point belongs to, an index into its own configuration's cars
            (:attr:`SkyConfiguration.cars <sdm.sky.SkyConfiguration>`: the car whose circle gave the
            point its depth), or ``None`` for a set packed without it (points and targets given by hand).
            :meth:`car_rows` numbers the cars across the set.
    """

    def __init__(self, points, pixels, offsets, targets, camera: Camera = APOLLO_CAMERA_5, image_ids=None,
                 rank: torch.Tensor | None = None, *, cars: torch.Tensor | None = None):
        self.points = points
        self.pixels = pixels
        self.offsets = offsets
        self.targets = targets
        self.camera = camera
        self.image_ids = list(image_ids) if image_ids is not None else [str(i) for i in range(len(self))]
        if targets.shape[1:] != camera.screen_shape:
            raise SDMInputError(f"targets have screen {tuple(targets.shape[1:])}, camera has {camera.screen_shape}")
        if cars is not None and (cars.shape != points.shape[:1] or cars.dtype != torch.int64):
            raise SDMInputError(f"cars must be a ({points.shape[0]},) int64 tensor (the car of each point), "
                                f"got {tuple(cars.shape)} {cars.dtype}")
        self.cars = cars
        self.rank = priority_rank(points[:, 2]) if rank is None else rank
        self._pyramids: dict[int, list[torch.Tensor]] = {}

    @classmethod
    def from_configurations(
        cls, configurations: Sequence[SkyConfiguration], camera: Camera = APOLLO_CAMERA_5
    ) -> "ConfigurationSet":
        """Pack configurations (empty ones allowed: they own no rows and contribute nothing).

        The car of each point (:attr:`cars`) is packed when every configuration with points records
        it (those of :func:`sdm.sky.build_configuration` and of a Sky file do), else it is ``None``.
        """
        if len(configurations) == 0:
            raise SDMInputError("cannot pack an empty list of configurations")
        for i, cfg in enumerate(configurations):
            if tuple(cfg.target.shape) != camera.screen_shape:
                raise SDMInputError(
                    f"configuration {i} ({cfg.image_id!r}) has a {tuple(cfg.target.shape)} target, "
                    f"the camera's screen is {camera.screen_shape}"
                )
        pixels = torch.cat([cfg.pixels for cfg in configurations])
        depth = torch.cat([cfg.depth.to(torch.float64) for cfg in configurations])
        device = pixels.device
        counts = torch.tensor([cfg.num_points for cfg in configurations], dtype=torch.int64, device=device)
        offsets = _offsets(counts)
        targets = torch.stack([cfg.target for cfg in configurations])
        if len(depth):
            points = pixel_centre_points(pixels, depth, camera)
        else:
            points = torch.zeros(0, 3, dtype=torch.float64, device=device)
        cars = None
        if all(cfg.cars is not None or cfg.num_points == 0 for cfg in configurations):
            empty = torch.zeros(0, dtype=torch.int64, device=device)
            cars = torch.cat([empty] + [cfg.cars.to(device=device, dtype=torch.int64)
                                        for cfg in configurations if cfg.cars is not None])
        return cls(points, pixels, offsets, targets, camera, [cfg.image_id for cfg in configurations], cars=cars)

    def __len__(self) -> int:
        return int(self.offsets.numel() - 1)

    @property
    def device(self) -> torch.device:
        """The device every tensor of the set lives on."""
        return self.points.device

    def to(self, device: torch.device | str) -> "ConfigurationSet":
        """The same set on ``device`` (``self`` when it is there already); float64 stays float64."""
        device = torch.device(device)
        if device == self.device:
            return self
        return ConfigurationSet(
            self.points.to(device), self.pixels.to(device), self.offsets.to(device), self.targets.to(device),
            self.camera, self.image_ids, rank=self.rank.to(device),
            cars=None if self.cars is None else self.cars.to(device),
        )

    @property
    def counts(self) -> torch.Tensor:
        """``(N,)`` int64 number of points per configuration."""
        return self.offsets[1:] - self.offsets[:-1]

    def check_indices(self, indices: Sequence[int] | torch.Tensor, name: str = "indices") -> torch.Tensor:
        """Configuration indices checked: ``(n,)`` int64 on the set's device.

        Negative indices are refused, not counted from the end (a negative offset in the CSR layout
        would gather another configuration's rows); so are floats and booleans (``0.5`` would be
        truncated, ``True`` read as 1).

        Raises:
            SDMInputError: naming ``name``, unless ``indices`` is a 1-D sequence of integers in ``[0, N)``.
        """
        try:
            values = torch.as_tensor(indices, device=self.device)
        except (TypeError, ValueError, RuntimeError):
            raise SDMInputError(f"{name} must be a 1-D sequence of integers, got {indices!r}") from None
        if values.numel() == 0:
            values = values.to(torch.int64)
        if values.ndim != 1 or values.dtype.is_floating_point or values.dtype.is_complex or values.dtype == torch.bool:
            raise SDMInputError(f"{name} must be a 1-D sequence of integers, got {indices!r}")
        values = values.to(torch.int64)
        if values.numel() and (int(values.min()) < 0 or int(values.max()) >= len(self)):
            raise SDMInputError(f"{name} must lie in [0, {len(self)}) (the set's configurations), "
                                f"got {int(values.min())}..{int(values.max())}")
        return values

    def rows(self, indices: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Rows of the given configurations: ``(row index (p,), batch-local config (p,))``."""
        starts = self.offsets[indices]
        counts = self.offsets[indices + 1] - starts
        local = torch.repeat_interleave(torch.arange(len(indices), device=self.device), counts)
        first_row = torch.cumsum(counts, 0) - counts
        rows = (starts - first_row).index_select(0, local) + torch.arange(local.numel(), device=self.device)
        return rows, local

    def batch(self, indices: Sequence[int] | torch.Tensor) -> PointBatch:
        """Gather configurations ``indices`` (integers in ``[0, N)``, repeats allowed) into a :class:`PointBatch`.

        Raises:
            SDMInputError: ``indices`` not a 1-D sequence of integers in ``[0, N)``.
        """
        indices = self.check_indices(indices)
        rows, local = self.rows(indices)
        return PointBatch(
            self.points.index_select(0, rows),
            self.pixels.index_select(0, rows),
            local,
            self.rank.index_select(0, rows),
            self.targets.index_select(0, indices),
        )

    def batches(self, batch_size: int) -> Iterator[tuple[torch.Tensor, PointBatch]]:
        """Consecutive batches of up to ``batch_size`` configurations, in order, for evaluation.

        Yields ``(indices, batch)``. A batch whose configurations are all empty has
        nothing to map and is skipped (its configurations keep whatever the caller
        counts for empty ones).
        """
        for first in range(0, len(self), batch_size):
            indices = torch.arange(first, min(first + batch_size, len(self)), device=self.device)
            batch = self.batch(indices)
            if batch.points.shape[0]:
                yield indices, batch

    def pyramid(self, steps: int) -> list[torch.Tensor]:
        """Zoomed-out targets of every configuration at levels ``0..steps`` (cached)."""
        if steps not in self._pyramids:
            self._pyramids[steps] = target_pyramid(self.targets, steps)
        return self._pyramids[steps]

    def subset(self, indices: Sequence[int]) -> "ConfigurationSet":
        """A new set with configurations ``indices`` (integers in ``[0, N)``), in that order."""
        indices = self.check_indices(indices)
        rows, _ = self.rows(indices)
        return ConfigurationSet(
            self.points[rows], self.pixels[rows], _offsets(self.counts[indices]), self.targets[indices], self.camera,
            [self.image_ids[i] for i in indices.tolist()], cars=None if self.cars is None else self.cars[rows],
        )

    def with_targets(self, targets: torch.Tensor) -> "ConfigurationSet":
        """The same points with other targets (e.g. noisy ones), ``(N, H, W)`` bool (moved to the set's device)."""
        if targets.shape != self.targets.shape:
            raise SDMInputError(f"targets must have shape {tuple(self.targets.shape)}, got {tuple(targets.shape)}")
        return ConfigurationSet(self.points, self.pixels, self.offsets, targets.bool().to(self.device), self.camera,
                                self.image_ids, rank=self.rank, cars=self.cars)

    def point_configs(self) -> torch.Tensor:
        """``(P,)`` int64 the configuration of each point, in ``[0, N)``, on the set's device."""
        return torch.repeat_interleave(torch.arange(len(self), device=self.device), self.counts)

    def car_rows(self) -> tuple[torch.Tensor, torch.Tensor]:
        """One parameter row per car that owns points: which row moves each point, and whose each row is.

        Rows are numbered configuration by configuration, and within a configuration by car index
        (:attr:`cars`). A car that owns no point (its disc hidden by nearer ones)
        gets no row; so does an empty configuration.

        Returns:
            ``(point_row, row_car)``, on the set's device:

            * ``point_row``: ``(P,)`` int64 the row of each point's car, in ``[0, R)``;
            * ``row_car``: ``(R, 2)`` int64 ``(configuration, car)`` of each row, configuration in
              ``[0, N)``, car an index into that configuration's cars; sorted, no repeats.

        Raises:
            SDMInputError: the set has no car index (:attr:`cars` is ``None``).
        """
        if self.cars is None:
            raise SDMInputError("this set has no car index (cars is None): pack it with "
                                "ConfigurationSet.from_configurations from configurations that record it "
                                "(sdm.sky.build_configuration, a Sky file)")
        configs = self.point_configs()
        stride = int(self.cars.max()) + 1 if self.cars.numel() else 1
        keys, point_row = torch.unique(configs * stride + self.cars, sorted=True, return_inverse=True)
        row_car = torch.stack((torch.div(keys, stride, rounding_mode="floor"), keys % stride), dim=1)
        return point_row, row_car


def _offsets(counts: torch.Tensor) -> torch.Tensor:
    """``(N + 1,)`` int64 CSR row offsets of configurations holding ``counts`` ``(N,)`` points (same device)."""
    return torch.cat((counts.new_zeros(1), counts.cumsum(0)))

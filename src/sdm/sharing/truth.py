"""theta* drawn from a seeded distribution per sharing, and the targets rendered from it
(:mod:`sdm.sharing`)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..batch import ConfigurationSet
from ..errors import SDMInputError
from ..sky import SKY_SHIFT, shifted_target
from .index import NO_INDEX, check_param_index, check_theta, point_shifts
from .kinds import Sharing


# -- theta*: seeded distributions -------------------------------------------------------------------


@dataclass(frozen=True)
class TruthDistribution:
    """How theta* is drawn for each sharing (metres; every draw independent, normal, per axis).

    * ``shared``: ``centre`` itself (the paper's theta*, no draw);
    * ``configuration``: each configuration's row ``centre + camera_sd * N(0, 1)``;
    * ``car``: each car's row ``centre + car_sd * N(0, 1)`` (cars of one image independent);
    * ``camera+car``: the camera rows as ``configuration``'s, each car's residual ``residual_sd * N(0, 1)``.

    Defaults: a camera offset of the paper's size with a spread of a few tens of centimetres (its
    shift is 0.6 m; a 0.15 m spread per axis puts 95 % of the draws within about 0.37 m of it), and a
    car residual of 5 cm per axis (a car's annotation error around its image's camera).

    Attributes:
        centre: the mean shift ``(a, b)``.
        camera_sd: spread of a configuration's (camera's) shift around ``centre``, per axis.
        car_sd: spread of a car's own shift around ``centre`` (the ``car`` sharing), per axis.
        residual_sd: spread of a car's residual around its camera (``camera+car``), per axis.
    """

    centre: tuple[float, float] = SKY_SHIFT
    camera_sd: float = 0.15
    car_sd: float = 0.15
    residual_sd: float = 0.05

    def __post_init__(self) -> None:
        if len(self.centre) != 2 or not all(math.isfinite(float(v)) for v in self.centre):
            raise SDMInputError(f"TruthDistribution.centre must be two finite numbers, got {self.centre!r}")
        for name in ("camera_sd", "car_sd", "residual_sd"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or value < 0:
                raise SDMInputError(f"TruthDistribution.{name} must be a non-negative number, got {value!r}")


def draw_truth(sharing: Sharing, seed: int, distribution: TruthDistribution = TruthDistribution()) -> torch.Tensor:
    """theta* of every row, drawn from ``distribution`` with a CPU generator seeded with ``seed``.

    Row ``k`` takes the ``k``-th pair of one ``(K, 2)`` standard normal draw (so the draw depends on the
    seed and the rows alone).

    Returns:
        ``(K, 2)`` float64 metres, on the device of ``sharing``'s tensors.
    """
    if isinstance(seed, bool) or int(seed) != seed or seed < 0:
        raise SDMInputError(f"seed must be a non-negative integer, got {seed!r}")
    device = sharing.rows.device
    centre = torch.tensor([float(v) for v in distribution.centre], dtype=torch.float64)
    if sharing.name == "shared":
        return centre.expand(sharing.n_rows, 2).clone().to(device)
    draw = torch.randn((sharing.n_rows, 2), generator=torch.Generator().manual_seed(int(seed)), dtype=torch.float64)
    is_car = sharing.rows[:, 1].cpu() != NO_INDEX
    if sharing.name == "configuration":
        truth = centre + distribution.camera_sd * draw
    elif sharing.name == "car":
        truth = centre + distribution.car_sd * draw
    else:
        truth = torch.where(is_car.unsqueeze(1), distribution.residual_sd * draw,
                            centre + distribution.camera_sd * draw)
    return truth.to(device)


# -- targets ------------------------------------------------------------------------------------------


def render_targets(data: ConfigurationSet, theta: torch.Tensor, param_index: torch.Tensor) -> torch.Tensor:
    """The targets of every configuration with each point moved by its own shift.

    Made as the paper's targets are (:func:`sdm.sky.shifted_target`): occupancy of
    ``floor(P(Q + (shift(q), 0)))``, points leaving the screen dropped.

    Args:
        theta: ``(K, 2)`` float64 metres (checked against ``param_index``).
        param_index: ``(P,)`` or ``(P, G)``.

    Returns:
        ``(N, H, W)`` bool on the set's device.
    """
    theta = check_theta(theta)
    index = check_param_index(param_index, data, theta.shape[0])
    shifts = point_shifts(theta.to(data.device), index)
    offsets = data.offsets.tolist()
    return torch.stack([shifted_target(data.points[start:stop], shifts[start:stop], data.camera)
                        for start, stop in zip(offsets[:-1], offsets[1:])])


def shifted_set(data: ConfigurationSet, theta: torch.Tensor, param_index: torch.Tensor) -> ConfigurationSet:
    """``data`` with the targets of :func:`render_targets` (the points unchanged)."""
    return data.with_targets(render_targets(data, theta, param_index))

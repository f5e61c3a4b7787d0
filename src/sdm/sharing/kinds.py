"""The sharings (:data:`SHARINGS`): which rows of ``theta`` move which points of a set, and what each
row stands for (:mod:`sdm.sharing`)."""
from __future__ import annotations

from dataclasses import dataclass

import torch

from ..batch import ConfigurationSet
from ..errors import SDMInputError
from .index import NO_INDEX

#: The sharings, from one row for everything to a row per car plus the camera.
SHARINGS = ("shared", "configuration", "car", "camera+car")
#: The sharings with rows of their own per configuration or car (Table 6's): every sharing but the paper's shared one.
ROW_SHARINGS = SHARINGS[1:]


# -- the sharings -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Sharing:
    """A parameter index with what its rows stand for.

    Attributes:
        name: one of :data:`SHARINGS`.
        param_index: ``(P,)`` int64 (``G = 1``) or ``(P, 2)`` int64 (``camera+car``), on the set's device.
        rows: ``(K, 2)`` int64 ``(configuration, car)`` of each row; :data:`NO_INDEX` where the row spans
            configurations (``shared``) or is no car's (``configuration``, a camera row).
        hidden: ``(H, 2)`` int64 ``(configuration, car)`` of the cars that own no point, hence no row (known
            only when the builder was given the number of cars per configuration; else empty).
    """

    name: str
    param_index: torch.Tensor
    rows: torch.Tensor
    hidden: torch.Tensor

    @property
    def n_rows(self) -> int:
        """``K``, the rows of ``theta``."""
        return int(self.rows.shape[0])


def _point_configs(data: ConfigurationSet) -> torch.Tensor:
    """``(P,)`` int64 configuration of each point."""
    return torch.repeat_interleave(torch.arange(len(data), device=data.device), data.counts)


def _no_hidden(device) -> torch.Tensor:
    return torch.zeros(0, 2, dtype=torch.int64, device=device)


def shared(data: ConfigurationSet) -> Sharing:
    """One row for every point: the paper's case (``param_index`` all 0, ``K = 1``)."""
    index = torch.zeros(data.points.shape[0], dtype=torch.int64, device=data.device)
    rows = torch.full((1, 2), NO_INDEX, dtype=torch.int64, device=data.device)
    return Sharing("shared", index, rows, _no_hidden(data.device))


def per_configuration(data: ConfigurationSet) -> Sharing:
    """One row per configuration that owns points, in configuration order (empty configurations get none).

    >>> from sdm import build_configuration
    >>> car = build_configuration(torch.tensor([[-3.0, 2.5, 20.0]], dtype=torch.float64))
    >>> empty = build_configuration(torch.zeros(0, 3, dtype=torch.float64))
    >>> rows = per_configuration(ConfigurationSet.from_configurations([car, empty, car]))
    >>> rows.n_rows, rows.rows[:, 0].tolist()  # configurations 0 and 2 own points, each its own row
    (2, [0, 2])
    """
    owners = (data.counts > 0).nonzero().squeeze(1)
    row_of_config = torch.full((len(data),), NO_INDEX, dtype=torch.int64, device=data.device)
    row_of_config[owners] = torch.arange(owners.numel(), device=data.device)
    index = row_of_config.index_select(0, _point_configs(data))
    rows = torch.stack((owners, torch.full_like(owners, NO_INDEX)), 1)
    return Sharing("configuration", index, rows, _no_hidden(data.device))


def check_cars(data: ConfigurationSet, cars, n_cars=None,
               name: str = "cars") -> tuple[torch.Tensor, torch.Tensor | None]:
    """The per-point car index (and the cars per configuration) checked.

    Args:
        cars: ``(P,)`` integers, each point's car within its configuration (``>= 0``).
        n_cars: optional ``(N,)`` integers, the cars of each configuration (on screen, hidden or not).

    Returns:
        ``(cars, n_cars)`` as int64 tensors on the set's device (``n_cars`` None when not given).

    Raises:
        SDMInputError: naming ``cars`` / ``n_cars``: wrong length, not integers, negative, or a car index
            not below its configuration's ``n_cars``.
    """
    def integers(values, length, what):
        try:
            values = torch.as_tensor(values, device=data.device)
        except (TypeError, ValueError, RuntimeError):
            raise SDMInputError(f"{what} must be a 1-D integer tensor, got {values!r}") from None
        if values.dtype.is_floating_point or values.dtype.is_complex or values.dtype == torch.bool:
            raise SDMInputError(f"{what} must hold integers, got dtype {values.dtype}")
        if values.ndim != 1 or values.shape[0] != length:
            raise SDMInputError(f"{what} must have shape ({length},), got {tuple(values.shape)}")
        values = values.to(torch.int64)
        if values.numel() and int(values.min()) < 0:
            raise SDMInputError(f"{what} must not be negative, got {int(values.min())}")
        return values

    cars = integers(cars, data.points.shape[0], name)
    if n_cars is None:
        return cars, None
    n_cars = integers(n_cars, len(data), "n_cars")
    if cars.numel():
        beyond = cars >= n_cars.index_select(0, _point_configs(data))
        if bool(beyond.any()):
            point = int(beyond.nonzero()[0])
            raise SDMInputError(f"{name}: point {point} names car {int(cars[point])}, beyond its configuration's "
                                f"n_cars")
    return cars, n_cars


def _car_rows(data: ConfigurationSet, cars, n_cars) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(row of each point, (config, car) per row, hidden (config, car))`` for one row per car owning points."""
    cars, n_cars = check_cars(data, cars, n_cars)
    config = _point_configs(data)
    width = int(cars.max()) + 1 if cars.numel() else 1
    if n_cars is not None and n_cars.numel():
        width = max(width, int(n_cars.max()))
    keys, index = torch.unique(config * width + cars, sorted=True, return_inverse=True)
    rows = torch.stack((torch.div(keys, width, rounding_mode="floor"), keys % width), 1)
    hidden = _no_hidden(data.device)
    if n_cars is not None:
        every = torch.repeat_interleave(torch.arange(len(data), device=data.device), n_cars) * width
        every = every + torch.cat([torch.arange(int(n), device=data.device) for n in n_cars.tolist()] or
                                  [torch.zeros(0, dtype=torch.int64, device=data.device)])
        missing = every[~torch.isin(every, keys)]
        hidden = torch.stack((torch.div(missing, width, rounding_mode="floor"), missing % width), 1)
    return index, rows, hidden


def per_car(data: ConfigurationSet, cars, n_cars=None) -> Sharing:
    """One row per car that owns points, configuration by configuration, cars in index order.

    Args:
        data: the set.
        cars: ``(P,)`` integers, each point's car within its configuration.
        n_cars: optional ``(N,)`` cars per configuration: the cars below it that own no point are listed in
            :attr:`Sharing.hidden`.
    """
    index, rows, hidden = _car_rows(data, cars, n_cars)
    return Sharing("car", index, rows, hidden)


def camera_and_car(data: ConfigurationSet, cars, n_cars=None) -> Sharing:
    """``G = 2``: each configuration's camera row (rows ``0..C-1``, configurations owning points, in order),
    then one residual row per car owning points (as :func:`per_car`, numbered from ``C``)."""
    camera = per_configuration(data)
    index, rows, hidden = _car_rows(data, cars, n_cars)
    param_index = torch.stack((camera.param_index, index + camera.n_rows), 1)
    return Sharing("camera+car", param_index, torch.cat((camera.rows, rows)), hidden)


def sharing(name: str, data: ConfigurationSet, cars=None, n_cars=None) -> Sharing:
    """The :class:`Sharing` called ``name`` (:data:`SHARINGS`); the car sharings need each point's car: ``cars``, or
    the set's own ``cars`` attribute where it has one.

    Raises:
        SDMInputError: naming ``name`` if unknown, or ``cars`` if a car sharing is asked without it.
    """
    cars = getattr(data, "cars", None) if cars is None else cars
    if name not in SHARINGS:
        raise SDMInputError(f"sharing must be one of {', '.join(SHARINGS)}, got {name!r}")
    if name in ("car", "camera+car") and cars is None:
        raise SDMInputError(f"cars: the {name!r} sharing needs each point's car")
    if name == "shared":
        return shared(data)
    if name == "configuration":
        return per_configuration(data)
    return (per_car if name == "car" else camera_and_car)(data, cars, n_cars)

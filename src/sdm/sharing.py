"""Parameters attached to points: which row of ``theta`` moves each point, and the camera as their sharing.

The paper's problem in general form: every point ``q`` of a configuration set is moved by its own shift,
the *sum* of ``G`` rows of a parameter table ``theta`` of ``K`` rows ``(a, b)`` (metres; ``z`` unchanged)::

    shift(q) = sum_g theta[param_index[q, g]]        param_index: (P,) or (P, G) int64 in [0, K)

A camera is a set of points that share rows. The sharing levels (:data:`LEVELS`):

* ``shared``: one row for every point of every configuration (the paper's case, ``K = 1``);
* ``configuration``: one row per configuration that owns points (each image its own camera offset);
* ``car``: one row per car that owns points (a point belongs to the car whose disc gave it its depth);
* ``camera+car``: ``G = 2``: column 0 the configuration's camera row, column 1 the car's residual row.

A car whose disc is fully hidden by nearer cars owns no point: it has no row, nothing pulls it, and it is
counted apart (:attr:`Sharing.hidden`, :func:`summarise_distances`).

What one configuration sees (:class:`Units`): its points move by the sums of a few distinct row tuples,
its *units* (its rows for ``configuration`` and ``car``; its cars' total shifts for ``camera+car``). A
method that solves each configuration alone (CMA-ES per configuration, its floor) estimates the units'
totals; :func:`unit_totals` gives any ``theta``'s totals, so every method is compared on the same units.
Under ``camera+car`` only the totals are identifiable from one configuration: ``camera + c`` and
``residual - c`` move every point alike.

Tensors live on the device of the set they describe; ``theta`` is float64 metres.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
import torch

from .batch import ConfigurationSet
from .errors import SDMInputError
from .sky import SKY_SHIFT, shifted_target

#: The sharing levels, from one row for everything to a row per car plus the camera.
LEVELS = ("shared", "configuration", "car", "camera+car")

#: ``car`` entry of a row table for a row that is no car's (a camera's, the shared one); also the
#: ``configuration`` entry of a row that spans configurations.
NO_INDEX = -1


# -- validation -----------------------------------------------------------------------------------


def _n_points(data: ConfigurationSet | int) -> int:
    return int(data.points.shape[0]) if isinstance(data, ConfigurationSet) else int(data)


def check_param_index(param_index, data: ConfigurationSet | int, n_rows: int | None,
                      name: str = "param_index") -> torch.Tensor:
    """``param_index`` checked against a set of ``P`` points and a ``theta`` of ``n_rows`` rows.

    Args:
        param_index: ``(P,)`` or ``(P, G)`` integer tensor (or nested sequence): the rows moving each point.
        data: the set (or its number of points ``P``).
        n_rows: ``K``, the rows of ``theta``; ``None``: as many as the index names (its largest entry + 1).
        name: what the messages call the argument.

    Returns:
        ``(P, G)`` int64 (a ``(P,)`` index as ``G = 1``), on the tensor's device.

    Raises:
        SDMInputError: naming ``name``: not an integer tensor (floats and booleans refused), not 1-D or
            2-D, not ``P`` entries long, no column, an entry negative or ``>= n_rows``; or naming the row
            (``row k of theta``) that no point uses (a row with no points has no pull: nothing could
            estimate it).
    """
    n_points = _n_points(data)
    if not isinstance(param_index, torch.Tensor):
        try:
            param_index = torch.as_tensor(param_index)
        except (TypeError, ValueError, RuntimeError):
            raise SDMInputError(f"{name} must be an integer tensor of shape (P,) or (P, G), got {param_index!r}") \
                from None
    index = param_index
    if index.dtype.is_floating_point or index.dtype.is_complex or index.dtype == torch.bool:
        raise SDMInputError(f"{name} must hold integers (row numbers), got dtype {index.dtype}")
    if index.ndim not in (1, 2):
        raise SDMInputError(f"{name} must have shape (P,) or (P, G), got {tuple(index.shape)}")
    if index.shape[0] != n_points:
        raise SDMInputError(f"{name} must have one entry per point: length {n_points}, got {index.shape[0]}")
    index = index.to(torch.int64)
    if index.ndim == 1:
        index = index.unsqueeze(1)
    if index.shape[1] == 0:
        raise SDMInputError(f"{name} must name at least one row per point, got shape {tuple(param_index.shape)}")
    if index.numel() and int(index.min()) < 0:
        raise SDMInputError(f"{name} must not be negative (rows are counted from 0), got {int(index.min())}")
    if n_rows is None:
        n_rows = int(index.max()) + 1 if index.numel() else 1
    if isinstance(n_rows, bool) or int(n_rows) != n_rows or n_rows < 1:
        raise SDMInputError(f"theta must have at least one row, got {n_rows!r} rows")
    if index.numel() and int(index.max()) >= n_rows:
        raise SDMInputError(f"{name} must lie in [0, {n_rows}) (the rows of theta), got {int(index.max())}")
    used = torch.bincount(index.reshape(-1), minlength=int(n_rows))
    empty = (used == 0).nonzero()
    if empty.numel():
        raise SDMInputError(f"{name}: row {int(empty[0])} of theta moves no point ({empty.numel()} such row(s)): "
                            "a row without points has nothing to estimate it from; drop it")
    return index


def check_theta(theta, n_rows: int | None = None, name: str = "theta") -> torch.Tensor:
    """``theta`` as a ``(K, 2)`` float64 tensor (``(a, b)`` per row, metres), checked.

    Raises:
        SDMInputError: naming ``name`` unless ``theta`` is ``(K, 2)`` finite numbers with ``K == n_rows``
            (when given).
    """
    try:
        values = torch.as_tensor(theta, dtype=torch.float64) if not isinstance(theta, torch.Tensor) else theta
    except (TypeError, ValueError, RuntimeError):
        raise SDMInputError(f"{name} must be a (K, 2) tensor of shifts (a, b), got {theta!r}") from None
    if values.ndim != 2 or values.shape[1] != 2:
        raise SDMInputError(f"{name} must have shape (K, 2), got {tuple(values.shape)}")
    if n_rows is not None and values.shape[0] != n_rows:
        raise SDMInputError(f"{name} has {values.shape[0]} rows, the parameter index names {n_rows}")
    if not values.is_floating_point() or not bool(torch.isfinite(values.detach()).all()):
        raise SDMInputError(f"{name} must hold finite numbers")
    return values


def point_shifts(theta: torch.Tensor, param_index: torch.Tensor, runs: torch.Tensor | None = None) -> torch.Tensor:
    """Each point's shift: the sum of its rows of ``theta``.

    Args:
        theta: ``(K, 2)`` metres, or ``(R, K, 2)`` (one table per run, with ``runs``); may require grad.
        param_index: ``(P, G)`` int64 (checked, :func:`check_param_index`), or ``(P,)``.
        runs: ``(P,)`` int64 the run of each point, for an ``(R, K, 2)`` ``theta``.

    Returns:
        ``(P, 2)`` in ``theta``'s dtype and device, differentiable in ``theta``. ``G = 1`` gathers the row
        unchanged (no addition), so the shared case moves every point by exactly ``theta[0]``.

    >>> theta = torch.tensor([[0.5, 0.3], [0.01, 0.0], [0.0, -0.02]], dtype=torch.float64)  # camera, two cars
    >>> point_shifts(theta, torch.tensor([[0, 1], [0, 1], [0, 2]]))  # (P, 2): each point's camera row + car row
    tensor([[0.5100, 0.3000],
            [0.5100, 0.3000],
            [0.5000, 0.2800]], dtype=torch.float64)
    """
    index = param_index if param_index.ndim == 2 else param_index.unsqueeze(1)
    if runs is not None:
        n_rows = theta.shape[-2]
        index = index + (runs * n_rows).unsqueeze(1)
        theta = theta.reshape(-1, theta.shape[-1])
    if index.shape[1] == 1:
        return theta.index_select(0, index[:, 0])
    shifts = theta.index_select(0, index[:, 0])
    for column in range(1, index.shape[1]):
        shifts = shifts + theta.index_select(0, index[:, column])
    return shifts


# -- the sharing levels -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Sharing:
    """A parameter index with what its rows stand for.

    Attributes:
        level: one of :data:`LEVELS`.
        param_index: ``(P,)`` int64 (``G = 1``) or ``(P, 2)`` int64 (``camera+car``), on the set's device.
        rows: ``(K, 2)`` int64 ``(configuration, car)`` of each row; :data:`NO_INDEX` where the row spans
            configurations (``shared``) or is no car's (``configuration``, a camera row).
        hidden: ``(H, 2)`` int64 ``(configuration, car)`` of the cars that own no point, hence no row (known
            only when the builder was given the number of cars per configuration; else empty).
    """

    level: str
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


def sharing(level: str, data: ConfigurationSet, cars=None, n_cars=None) -> Sharing:
    """The :class:`Sharing` of ``level`` (:data:`LEVELS`); the car levels need each point's car: ``cars``, or
    the set's own ``cars`` attribute where it has one.

    Raises:
        SDMInputError: naming ``level`` if unknown, or ``cars`` if a car level is asked without it.
    """
    cars = getattr(data, "cars", None) if cars is None else cars
    if level not in LEVELS:
        raise SDMInputError(f"level must be one of {', '.join(LEVELS)}, got {level!r}")
    if level in ("car", "camera+car") and cars is None:
        raise SDMInputError(f"cars: the {level!r} level needs each point's car")
    if level == "shared":
        return shared(data)
    if level == "configuration":
        return per_configuration(data)
    return (per_car if level == "car" else camera_and_car)(data, cars, n_cars)


# -- theta*: seeded distributions -------------------------------------------------------------------


@dataclass(frozen=True)
class TruthDistribution:
    """How theta* is drawn for each sharing level (metres; every draw independent, normal, per axis).

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
        car_sd: spread of a car's own shift around ``centre`` (``car`` level), per axis.
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
    if sharing.level == "shared":
        return centre.expand(sharing.n_rows, 2).clone().to(device)
    draw = torch.randn((sharing.n_rows, 2), generator=torch.Generator().manual_seed(int(seed)), dtype=torch.float64)
    is_car = sharing.rows[:, 1].cpu() != NO_INDEX
    if sharing.level == "configuration":
        truth = centre + distribution.camera_sd * draw
    elif sharing.level == "car":
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


# -- what one configuration sees ------------------------------------------------------------------------


@dataclass(frozen=True)
class Units:
    """The unknowns of each configuration alone: the distinct row tuples its points sum.

    Units are numbered configuration by configuration, each configuration's in the order of their rows.

    Attributes:
        point_unit: ``(P,)`` int64 the unit of each point.
        rows: ``(U, G)`` int64 the rows each unit sums.
        config: ``(U,)`` int64 the configuration of each unit.
        offsets: ``(N + 1,)`` int64 configuration ``i`` owns units ``offsets[i]:offsets[i + 1]``.
    """

    point_unit: torch.Tensor
    rows: torch.Tensor
    config: torch.Tensor
    offsets: torch.Tensor

    def __len__(self) -> int:
        return int(self.rows.shape[0])


def units(data: ConfigurationSet, param_index: torch.Tensor, n_rows: int | None = None) -> Units:
    """The :class:`Units` of a set under ``param_index`` (checked against ``n_rows`` rows, default its max + 1)."""
    raw = torch.as_tensor(param_index)
    if n_rows is None:
        n_rows = int(raw.max()) + 1 if raw.numel() and not raw.dtype.is_floating_point else 1
    index = check_param_index(param_index, data, n_rows)
    config = _point_configs(data)
    keys, point_unit = torch.unique(torch.cat((config.unsqueeze(1), index), 1), dim=0, return_inverse=True)
    counts = torch.bincount(keys[:, 0], minlength=len(data))
    offsets = torch.cat((counts.new_zeros(1), counts.cumsum(0)))
    return Units(point_unit, keys[:, 1:], keys[:, 0], offsets)


def unit_totals(theta: torch.Tensor, units: Units) -> torch.Tensor:
    """``(U, 2)`` each unit's total shift under ``theta`` (``(K, 2)``), as :func:`point_shifts` sums it."""
    return point_shifts(theta, units.rows)


def theta_from_totals(totals: torch.Tensor, units: Units, n_rows: int) -> torch.Tensor:
    """``(K, 2)`` theta whose units' totals are ``totals`` (``(U, 2)``), where that theta is unique.

    Raises:
        SDMInputError: naming ``units`` unless each unit is one row (``G = 1``) and each row is one
            configuration's (no row spans configurations): otherwise only the totals are estimated.
    """
    rows = units.rows
    if rows.shape[1] != 1 or rows.shape[0] != n_rows or not torch.equal(
            torch.sort(rows[:, 0]).values, torch.arange(n_rows, device=rows.device)):
        raise SDMInputError("units: a theta follows from the units' totals only when each unit is one row of its "
                            "own (one row per configuration or per car); compare totals (unit_totals) instead")
    theta = torch.empty(n_rows, 2, dtype=totals.dtype, device=totals.device)
    theta[rows[:, 0]] = totals
    return theta


# -- distances ------------------------------------------------------------------------------------------


def row_distances(estimate: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """``(K,)`` float64 ``||estimate_k - truth_k||``, metres, of two ``(K, 2)`` tables (rows or unit totals)."""
    estimate, truth = check_theta(estimate, name="estimate"), check_theta(truth, name="truth")
    if estimate.shape != truth.shape:
        raise SDMInputError(f"estimate has shape {tuple(estimate.shape)}, truth {tuple(truth.shape)}")
    return torch.linalg.vector_norm(estimate.detach().double() - truth.detach().double(), dim=1)


@dataclass(frozen=True)
class DistanceSummary:
    """Mean, median and third quartile of the distances of the rows counted (metres).

    Attributes:
        counted: rows in the statistics.
        hidden: cars left out: rows flagged hidden plus hidden cars that have no row.
    """

    mean: float
    median: float
    q3: float
    counted: int
    hidden: int


def summarise_distances(distances: torch.Tensor, hidden: torch.Tensor | None = None,
                        hidden_without_row: int = 0) -> DistanceSummary:
    """:class:`DistanceSummary` of ``(K,)`` distances, leaving out the rows flagged ``hidden`` (``(K,)`` bool).

    Quantiles interpolate linearly (numpy's default). With no row counted the statistics are NaN.
    ``hidden_without_row`` (e.g. ``len(sharing.hidden)``) is added to the hidden count.
    """
    distances = torch.as_tensor(distances, dtype=torch.float64).reshape(-1)
    keep = torch.ones_like(distances, dtype=torch.bool) if hidden is None else ~torch.as_tensor(hidden).bool()
    if keep.shape != distances.shape:
        raise SDMInputError(f"hidden must have shape {tuple(distances.shape)}, got {tuple(keep.shape)}")
    if isinstance(hidden_without_row, bool) or int(hidden_without_row) != hidden_without_row or hidden_without_row < 0:
        raise SDMInputError(f"hidden_without_row must be a non-negative integer, got {hidden_without_row!r}")
    kept = distances[keep.to(distances.device)]
    n_hidden = int((~keep).sum()) + int(hidden_without_row)
    if kept.numel() == 0:
        return DistanceSummary(math.nan, math.nan, math.nan, 0, n_hidden)
    quantiles = torch.quantile(kept, torch.tensor([0.5, 0.75], dtype=torch.float64, device=kept.device)).tolist()
    return DistanceSummary(float(kept.mean()), quantiles[0], quantiles[1], int(kept.numel()), n_hidden)


__all__ = [
    "LEVELS", "NO_INDEX", "DistanceSummary", "Sharing", "TruthDistribution", "Units", "camera_and_car",
    "check_cars", "check_param_index", "check_theta", "draw_truth", "per_car", "per_configuration",
    "point_shifts", "render_targets", "row_distances", "shared", "shifted_set", "sharing",
    "summarise_distances", "theta_from_totals", "unit_totals", "units",
]

"""What one configuration sees: its units (the distinct row tuples its points sum), their totals, and the
distances every method is scored by (:mod:`sdm.sharing`)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..batch import ConfigurationSet
from ..errors import SDMInputError
from .index import check_param_index, check_theta, point_shifts
from .kinds import _point_configs


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

"""The parameter index per point, checked against a set and a ``theta``, and the shift each point gets from
it (:mod:`sdm.sharing`).

Tensors live on the device of the set they describe; ``theta`` is float64 metres.
"""
from __future__ import annotations

import torch

from ..batch import ConfigurationSet
from ..errors import SDMInputError

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

"""What a configuration's pixels identify: the set of a unit's shifts that reproduce its noise-free target exactly.

A unit's points move by whole screen pixels (:func:`sdm.representation.screen_pixels` floors them), so the exact
mismatch of its configuration is flat over a cell of shifts around theta*. Every shift of that cell is as good an
answer as theta* itself: no method that reads the pixels can tell them apart. :func:`exact_sets` scans a grid of
shifts of each unit (the configuration's other units at theta*) and keeps those whose rendering equals the target
pixel for pixel (:class:`sdm.experiments.baselines.rows.ConfigurationMismatch` counts 0). Of that set it reports the extent per
axis and the mean distance of its points from theta*: the error of a method that lands anywhere in the set.

For a car of pixel-centre points at depth ``z`` and theta* on its build shift the set is the rectangle
``[-dx/2, dx/2) x [-dy/2, dy/2)``, ``(dy, dx) = camera.metres_per_screen_pixel(z)`` (``tests/experiments/test_identifiability.py``).

Tensors: ``(U, 2)`` float64 metres ``(a, b)``, on the set's device.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .baselines.rows import ConfigurationMismatch, configuration_objective
from ..batch import ConfigurationSet
from ..errors import SDMInputError
from ..representation import screen_pixels
from ..sharing import Units
from ..sky import shift_vector

#: Cells of the mismatch's stamp buffer one pass may use (candidates x window pixels): about 256 MB of int64.
STAMP_CELLS = 1 << 25


@dataclass(frozen=True)
class ExactSets:
    """The scanned sets of :func:`exact_sets`, one per unit asked for.

    Attributes:
        unit: ``(V,)`` int64 the units scanned.
        points: ``(V,)`` int64 grid points in each set.
        low, high: ``(V, 2)`` float64 metres: the set's smallest and largest offset from theta* per axis
            (``(a, b)``), NaN for an empty set.
        extent: ``(V, 2)`` float64 metres: ``high - low + step`` per axis, each grid point standing for a
            cell of side ``step`` (an interval of width ``w`` reads as ``w`` to within one step).
        distance: ``(V,)`` float64 metres: the mean distance of the set's grid points from theta*.
        clipped: ``(V,)`` bool: the set touches the scan's border (its extent is then a lower bound).
        step: the grid's spacing, metres.
    """

    unit: torch.Tensor
    points: torch.Tensor
    low: torch.Tensor
    high: torch.Tensor
    extent: torch.Tensor
    distance: torch.Tensor
    clipped: torch.Tensor
    step: float


def scan_offsets(reach: float, step: float, dtype=torch.float64, device=None) -> torch.Tensor:
    """``(C, 2)`` the grid ``{-n..n} * step`` squared (``n = ceil(reach / step)``), ``a`` varying slowest."""
    if not (math.isfinite(reach) and math.isfinite(step)) or reach <= 0 or step <= 0:
        raise SDMInputError(f"reach and step must be positive numbers, got reach={reach!r}, step={step!r}")
    n = math.ceil(reach / step)
    axis = torch.arange(-n, n + 1, dtype=dtype, device=device) * step
    return torch.cartesian_prod(axis, axis)


def exact_sets(data: ConfigurationSet, units: Units, truth: torch.Tensor, scan=None, reach: float = 0.6,
               step: float = 0.01) -> ExactSets:
    """For each unit in ``scan``, the shifts that reproduce its configuration's target exactly, the others at theta*.

    Args:
        data: the configurations; their targets must be the noise-free rendering of ``truth`` (e.g.
            :func:`sdm.sharing.render_targets` at theta*).
        units: the units of ``data`` (:func:`sdm.sharing.units`).
        truth: ``(U, 2)`` float64 metres, theta*'s total per unit (:func:`sdm.sharing.unit_totals`).
        scan: the units to scan (a sequence or ``(V,)`` tensor of unit numbers); ``None``: every unit.
        reach: half-width of the scanned square around theta*, metres.
        step: the grid's spacing, metres.

    Returns:
        :class:`ExactSets`.

    Raises:
        SDMInputError: naming ``truth`` unless it is ``(U, 2)``, or where a configuration's target is not its
            exact rendering at ``truth`` (theta* itself would not be in the set); naming ``scan`` for a unit out
            of range; naming ``reach`` or ``step`` unless both are positive.
    """
    if truth.ndim != 2 or truth.shape != (len(units), 2):
        raise SDMInputError(f"truth must be (U, 2) = ({len(units)}, 2), got {tuple(truth.shape)}")
    chosen = torch.arange(len(units)) if scan is None else torch.as_tensor(scan, dtype=torch.int64).reshape(-1)
    if chosen.numel() and (int(chosen.min()) < 0 or int(chosen.max()) >= len(units)):
        raise SDMInputError(f"scan must name units in [0, {len(units)}), got {chosen.tolist()}")
    truth = truth.to(device=data.device, dtype=torch.float64)
    offsets = scan_offsets(reach, step, device=data.device)
    config_of = units.config.cpu()
    checked = set()
    rows = []
    for unit in chosen.tolist():
        index = int(config_of[unit])
        first, last = int(units.offsets[index]), int(units.offsets[index + 1])
        if index not in checked:
            if int(configuration_objective(data, units, index).counts(truth[first:last].unsqueeze(0))[0]) != 0:
                raise SDMInputError(f"truth: configuration {index}'s target is not its exact rendering at truth "
                                    "(give the noise-free targets rendered at theta*)")
            checked.add(index)
        objective = _unit_objective(data, units, truth, index, unit, reach)
        start = truth[unit].expand(1, 1, 2)
        chunk = max(1, STAMP_CELLS // objective.cells)
        found = []
        for begin in range(0, offsets.shape[0], chunk):
            part = offsets[begin:begin + chunk]
            shifts = torch.cat((start + part.unsqueeze(1), part.new_zeros(part.shape[0], 1, 2)), 1)
            found.append(part[objective.counts(shifts) == 0])
        rows.append(torch.cat(found))
    return _summary(chosen, rows, reach, step)


def _unit_objective(data: ConfigurationSet, units: Units, truth: torch.Tensor, index: int, unit: int,
                    reach: float) -> ConfigurationMismatch:
    """The exact mismatch of configuration ``index`` as a function of ``unit``'s shift alone, in a window.

    Two units: 0 the scanned unit's points (unshifted), 1 the configuration's other points moved by their
    units' theta* beforehand (to be given shift 0, so they land exactly where theta* puts them). The window
    holds every pixel the scanned unit can reach within ``reach`` metres of any shift of the scan; the other
    points outside it never change a pixel the scan can, so the count within it is the whole mismatch.
    """
    begin, end = int(data.offsets[index]), int(data.offsets[index + 1])
    points = data.points[begin:end]
    mine = units.point_unit[begin:end] == unit
    moved = points + shift_vector(truth.index_select(0, units.point_unit[begin:end]), points)
    camera = data.camera
    pixels, _ = screen_pixels(camera.project(moved, validate=False), camera)
    nearest = float(points[mine, 2].min())
    reach_px = (math.ceil(reach * camera.fy * camera.rows_per_image_pixel / nearest) + 2,
                math.ceil(reach * camera.fx * camera.cols_per_image_pixel / nearest) + 2)
    height, width = camera.screen_shape
    low = (pixels[mine].min(0).values - torch.tensor(reach_px, device=pixels.device)).tolist()
    high = (pixels[mine].max(0).values + torch.tensor(reach_px, device=pixels.device)).tolist()
    top, left = max(low[0], 0), max(low[1], 0)
    bottom, right = min(high[0], height - 1), min(high[1], width - 1)
    if bottom < top or right < left:  # the unit is off screen wherever the scan moves it
        top, left, bottom, right = 0, 0, 0, 0
    near = (~mine) & (pixels[:, 0] >= top) & (pixels[:, 0] <= bottom) & (pixels[:, 1] >= left) \
        & (pixels[:, 1] <= right)
    kept = torch.cat((points[mine], moved[near]))
    which = torch.cat((torch.zeros(int(mine.sum()), dtype=torch.int64, device=points.device),
                       torch.ones(int(near.sum()), dtype=torch.int64, device=points.device)))
    return ConfigurationMismatch(kept, which, data.targets[index], camera,
                                 window=(top, left, bottom - top + 1, right - left + 1))


def _summary(chosen: torch.Tensor, sets: list[torch.Tensor], reach: float, step: float) -> ExactSets:
    nan = torch.full((2,), math.nan, dtype=torch.float64)
    low = torch.stack([s.min(0).values.cpu() if len(s) else nan for s in sets]) if sets else torch.empty(0, 2)
    high = torch.stack([s.max(0).values.cpu() if len(s) else nan for s in sets]) if sets else torch.empty(0, 2)
    distance = torch.tensor([float(s.norm(dim=1).mean()) if len(s) else math.nan for s in sets], dtype=torch.float64)
    edge = math.ceil(reach / step) * step - step / 2
    clipped = ((low.abs() >= edge) | (high.abs() >= edge)).any(1) if sets else torch.empty(0, dtype=torch.bool)
    return ExactSets(unit=chosen, points=torch.tensor([len(s) for s in sets], dtype=torch.int64), low=low, high=high,
                     extent=high - low + step, distance=distance, clipped=clipped, step=float(step))

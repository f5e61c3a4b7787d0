"""Parameters attached to points: which row of ``theta`` moves each point, and the camera as their sharing.

The paper's problem in general form: every point ``q`` of a configuration set is moved by its own shift,
the *sum* of ``G`` rows of a parameter table ``theta`` of ``K`` rows ``(a, b)`` (metres; ``z`` unchanged)::

    shift(q) = sum_g theta[param_index[q, g]]        param_index: (P,) or (P, G) int64 in [0, K)

A camera is a set of points that share rows. The sharings (:data:`SHARINGS`):

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

from .index import NO_INDEX, check_param_index, check_theta, point_shifts
from .kinds import SHARINGS, ROW_SHARINGS, Sharing, camera_and_car, check_cars, per_car, per_configuration, shared, sharing
from .truth import TruthDistribution, draw_truth, render_targets, shifted_set
from .units import DistanceSummary, Units, row_distances, summarise_distances, theta_from_totals, unit_totals, units

__all__ = [
    "SHARINGS", "NO_INDEX", "ROW_SHARINGS", "DistanceSummary", "Sharing", "TruthDistribution", "Units", "camera_and_car",
    "check_cars", "check_param_index", "check_theta", "draw_truth", "per_car", "per_configuration",
    "point_shifts", "render_targets", "row_distances", "shared", "shifted_set", "sharing",
    "summarise_distances", "theta_from_totals", "unit_totals", "units",
]

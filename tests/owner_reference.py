"""Reference for the car each point of ``E'`` belongs to: a loop over points and cars, no scatter, no sort.

A point's car is the one whose disc covers its pixel with the smallest depth; of cars at equal depth,
the one listed first in ``centres`` (row-major order of ``E``). The product (``sdm.sky.paint_circles``)
must give the same index for every point.
"""
from __future__ import annotations

import math

import torch

from sdm.sky import CIRCLE_RADIUS


def reference_cars(pixels: torch.Tensor, centres: torch.Tensor, centre_depth: torch.Tensor,
                   radius: float = CIRCLE_RADIUS) -> list[int]:
    """The car of each point: ``pixels`` ``(K, 2)``, ``centres`` ``(M, 2)``, ``centre_depth`` ``(M,)``."""
    owners = []
    for row, col in pixels.tolist():
        best = None
        for car, ((c_row, c_col), depth) in enumerate(zip(centres.tolist(), centre_depth.tolist())):
            if math.hypot(row - c_row, col - c_col) <= radius and (best is None or depth < best[0]):
                best = (depth, car)  # strictly nearer only: an equal depth keeps the earlier car
        owners.append(-1 if best is None else best[1])
    return owners

"""Brute-force references for the floor (sdm.experiments.baselines.floor): every cell of the pixel mismatch in a window.

The count is a step function of ``theta`` that changes only where some point's column (a function of
``a`` alone) or row (of ``b`` alone) crosses a pixel border: at ``a = (k - col_0) / g_c`` and
``b = (k - row_0) / g_r`` for integers ``k``. Between consecutive borders of both axes it is constant,
so counting it once per cell of that product grid (at the cell's midpoint) gives its minimum over a
window exactly. Written plainly (numpy, every point's every border), for tiny scenes only.
"""
from __future__ import annotations

import numpy as np

from sdm.experiments.baselines.mismatch import PixelMismatch, _projection


def borders(train_set, axis: int, low: float, high: float) -> np.ndarray:
    """Sorted distinct values in ``[low, high]`` of theta's ``axis`` (0: a, 1: b) where some point's pixel changes."""
    origin, gain = _projection(train_set.points, train_set.camera)
    screen = 1 - axis  # a moves the column (screen axis 1), b the row (screen axis 0)
    start = origin[:, screen].numpy()
    rate = gain[:, screen].numpy()
    values = []
    for s, g in zip(start, rate):
        first, last = np.ceil(s + low * g), np.floor(s + high * g)
        if last >= first:
            values.append((np.arange(first, last + 1) - s) / g)
    if not values:
        return np.array([low, high])
    return np.unique(np.concatenate([[low, high], *values]).clip(low, high))


def cell_minimum(objective: PixelMismatch, centre, half_width: float, max_cells: int = 200_000):
    """``(count, theta)``: the lowest count of every grid cell in the square ``centre +- half_width`` (metres)
    and the midpoint of the first such cell (a-major order); :class:`AssertionError` if over ``max_cells``."""
    train_set = objective.train_set
    a_borders = borders(train_set, 0, centre[0] - half_width, centre[0] + half_width)
    b_borders = borders(train_set, 1, centre[1] - half_width, centre[1] + half_width)
    a_mid = 0.5 * (a_borders[1:] + a_borders[:-1])
    b_mid = 0.5 * (b_borders[1:] + b_borders[:-1])
    assert a_mid.size * b_mid.size <= max_cells, (a_mid.size, b_mid.size)
    best = (None, None)
    for a in a_mid:
        thetas = [(float(a), float(b)) for b in b_mid]
        counts = objective.many(thetas)
        index = int(np.argmin(counts))
        if best[0] is None or counts[index] < best[0]:
            best = (counts[index], thetas[index])
    return best


def grid_minimum(objective: PixelMismatch, centre, half_width: float, step: float):
    """``(count, theta)``: the lowest count on the regular grid ``centre + step (i, j)`` within ``+- half_width``."""
    offsets = np.arange(-half_width, half_width + step / 2, step)
    best = (None, None)
    for da in offsets:
        thetas = [(float(centre[0] + da), float(centre[1] + db)) for db in offsets]
        counts = objective.many(thetas)
        index = int(np.argmin(counts))
        if best[0] is None or counts[index] < best[0]:
            best = (counts[index], thetas[index])
    return best

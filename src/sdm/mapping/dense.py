"""The dense SDM reference: the paper's grid formulation, written for reading, not speed.

Every level works on whole ``(n, 4^k, h, w)`` grids of sub-representations
(:func:`sdm.zoom.space_to_depth`), exactly as section 4.1 of the paper builds
them:

1. For each active cell, the nine *XY-adjustments* ``T``: the points at the
   cell's depth that project onto the centres of the 3x3 neighbouring blocks
   (on the original screen: ``((I + k + 0.5) B, (J + l + 0.5) B)``).
2. The kernel ``D = softmax(-c ||p - T||)`` over the nine (the paper prints
   ``+c``; the nearest adjustment must get the largest weight).
3. Aggregation ``C`` (Comment 1): an entry of ``D`` counts as 1 when it exceeds
   1/2 and as 0 otherwise (the paper's "c large enough"); each output cell takes
   the ``rmin`` of the points whose kernel selects it. With a finite ``c`` a
   point within about ``1/c`` metres of a block boundary selects nothing and
   disappears; as ``c`` grows the output converges to the fast path's.
4. The inverse reshape restores the full-resolution screen for the next level.

At the loss level the dynamic gradient flow (eq. 19) is read off the same
grids: the landing adjustment is the nearest one (``argmax D``; the backward
"removes the role of the kernel"), and an unmatched point is pulled by
``sign(p - T)`` towards every other adjustment whose block is active in the
zoomed-out target.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

from ..camera import Camera
from ..errors import SDMInputError
from ..zoom import depth_to_space, space_to_depth
from .result import MappingResult

_OFFSETS = [(dk, dl) for dk in (-1, 0, 1) for dl in (-1, 0, 1)]
_NO_RANK = torch.iinfo(torch.int64).max


def dense_mapping(
    points: torch.Tensor,
    pixels: torch.Tensor,
    config: torch.Tensor,
    rank: torch.Tensor,
    target: torch.Tensor,
    steps: int,
    zoom: int,
    camera: Camera,
    c: float = 1e9,
) -> MappingResult:
    """Grid-formulation SDM over levels ``steps..zoom``; same contract as :func:`~sdm.mapping.fast.fast_mapping`.

    Args:
        points, pixels, config, rank, target, steps, zoom, camera: as in
            :func:`~sdm.mapping.fast.fast_mapping`; each configuration must hold
            at most one point per pixel (a proper 2D representation).
        c: kernel shape constant, 1/metres.

    Returns:
        :class:`MappingResult`.
    """
    height, width = camera.screen_shape
    n_configs, n_points = int(target.shape[0]), points.shape[0]
    cell = (config * height + pixels[:, 0]) * width + pixels[:, 1]
    if torch.unique(cell).numel() != n_points:
        raise SDMInputError("the dense SDM path needs at most one point per pixel in each configuration")

    # Full-resolution grids of the input representation I~: one channel per quantity.
    grid = {
        "x": _scatter(cell, points[:, 0], n_configs, camera, 0.0),
        "y": _scatter(cell, points[:, 1], n_configs, camera, 0.0),
        "z": _scatter(cell, points[:, 2], n_configs, camera, 0.0),
        "id": _scatter(cell, torch.arange(n_points), n_configs, camera, -1),
        "rank": _scatter(cell, rank, n_configs, camera, _NO_RANK),
    }
    for level in range(steps, zoom - 1, -1):
        sub = {name: space_to_depth(values, level) for name, values in grid.items()}
        active = sub["id"] >= 0  # (n, S, h, w)
        adjustments = _adjustments(sub["z"], level, camera)  # (n, S, 9, h, w, 2) metres
        offset = torch.stack((sub["x"], sub["y"]), -1)[:, :, None] - adjustments  # p - T
        distance = offset.norm(dim=-1)  # (n, S, 9, h, w)
        kernel = torch.softmax(-c * distance, dim=2)
        selected = (kernel > 0.5) & active[:, :, None]
        if level == zoom:
            flow_grid, loss, matched_grid, landed_grid = _dynamic_flow(kernel, offset, active, target, sub["z"].shape)
            ids = sub["id"]
        sub = _aggregate(sub, selected)
        grid = {name: depth_to_space(values, level) for name, values in sub.items()}

    out_pixels = torch.full((n_points, 2), -1, dtype=torch.int64)
    out_id = grid["id"]
    where = (out_id >= 0).nonzero()
    out_pixels[out_id[out_id >= 0]] = where[:, 1:]
    flow = torch.zeros(n_points, 2, dtype=points.dtype)
    matched = torch.zeros(n_points, dtype=torch.bool)
    entered = torch.zeros(n_points, dtype=torch.bool)
    landed = torch.zeros(n_points, dtype=torch.bool)
    present = ids >= 0
    landed[ids[present]] = landed_grid[present]
    flow[ids[present]] = flow_grid[present]
    matched[ids[present]] = matched_grid[present]
    entered[ids[present]] = True
    return MappingResult(out_pixels, flow, loss, entered, matched, zoom, landed)


def _scatter(cell, values, n_configs, camera, empty):
    height, width = camera.screen_shape
    grid = torch.full((n_configs * height * width,), empty, dtype=values.dtype)
    grid[cell] = values
    return grid.view(n_configs, height, width)


def _adjustments(depth: torch.Tensor, level: int, camera: Camera) -> torch.Tensor:
    """XY-adjustments ``T``: ``(n, S, 9, h, w, 2)`` (x, y) in metres at each cell's depth."""
    block_size = 1 << level
    h, w = depth.shape[-2:]
    rows = torch.arange(h, dtype=depth.dtype)[:, None].expand(h, w)
    cols = torch.arange(w, dtype=depth.dtype)[None, :].expand(h, w)
    safe_depth = torch.where(depth > 0, depth, torch.ones_like(depth))  # inactive cells: any valid depth
    adjustments = []
    for dk, dl in _OFFSETS:
        centre = torch.stack(((rows + dk + 0.5) * block_size, (cols + dl + 0.5) * block_size), -1)
        points = camera.backproject(centre.expand(*depth.shape, 2), safe_depth)
        adjustments.append(points[..., :2])
    return torch.stack(adjustments, dim=2)


def _shift(values: torch.Tensor, dk: int, dl: int, fill) -> torch.Tensor:
    """``out[..., I, J] = values[..., I - dk, J - dl]`` (``fill`` outside the grid)."""
    is_bool = values.dtype == torch.bool
    padded = F.pad(values.to(torch.uint8) if is_bool else values, (1, 1, 1, 1), value=fill)
    h, w = values.shape[-2:]
    out = padded[..., 1 - dk : 1 - dk + h, 1 - dl : 1 - dl + w]
    return out.bool() if is_bool else out


def _aggregate(sub: dict, selected: torch.Tensor) -> dict:
    """Comment 1: each cell takes the ``rmin`` of the points whose kernel selects it.

    ``rmin``: the smallest depth wins; among equal depths the smallest priority rank.
    """
    candidates_z, candidates_rank, sources = [], [], []
    for index, (dk, dl) in enumerate(_OFFSETS):
        chosen = _shift(selected[:, :, index], dk, dl, False)
        shifted = {name: _shift(values, dk, dl, 0) for name, values in sub.items()}
        candidates_z.append(torch.where(chosen, shifted["z"], torch.inf))
        candidates_rank.append(torch.where(chosen, shifted["rank"], _NO_RANK))
        sources.append(shifted)
    z = torch.stack(candidates_z, 2)  # (n, S, 9, h, w)
    nearest = z.min(2, keepdim=True).values
    rank = torch.where((z == nearest) & torch.isfinite(z), torch.stack(candidates_rank, 2), _NO_RANK)
    best = rank.argmin(2, keepdim=True)
    occupied = torch.isfinite(nearest).squeeze(2)
    out = {}
    for name, empty in (("x", 0.0), ("y", 0.0), ("z", 0.0), ("id", -1), ("rank", _NO_RANK)):
        stacked = torch.stack([source[name] for source in sources], 2)
        out[name] = torch.where(occupied, stacked.gather(2, best).squeeze(2), empty)
    return out


def _dynamic_flow(kernel, offset, active, target, shape):
    """Eq. 19 on grids: ``(flow (n, S, h, w, 2), loss (), matched, landed (n, S, h, w))``."""
    n_configs, n_subreps, h, w = shape
    window = torch.stack([_shift(target, -dk, -dl, False) for dk, dl in _OFFSETS], 1)  # (n, 9, h, w): target at I+dk
    window = window[:, None].expand(n_configs, n_subreps, 9, h, w)
    on_grid = torch.stack([_shift(torch.ones_like(target), -dk, -dl, False) for dk, dl in _OFFSETS], 1)[:, None]
    nearest = kernel.argmax(2, keepdim=True)  # (n, S, 1, h, w)
    landed_on_grid = on_grid.expand_as(window).gather(2, nearest).squeeze(2)
    matched = active & window.gather(2, nearest).squeeze(2)
    pulled = active & landed_on_grid & ~matched
    others = torch.ones_like(window).scatter(2, nearest, False)
    weight = (window & others & pulled[:, :, None]).to(offset.dtype)[..., None]  # (n, S, 9, h, w, 1)
    flow = (torch.sign(offset) * weight).sum(2)
    loss = (offset.abs() * weight).sum()
    return flow, loss, matched, active & landed_on_grid

"""The dense SDM reference: the paper's grid formulation, written for reading, not speed.

Every zoom ``k`` works on whole ``(n, 4^k, h, w)`` grids of sub-representations
(:func:`sdm.zoom.space_to_depth`), exactly as section 4.1 of the paper builds
them:

1. For each active cell, the nine *XY-adjustments* ``T``: the points at the
   cell's depth that project onto the centres of the 3x3 neighbouring blocks
   (on the original screen: ``((I + k + 0.5) B, (J + l + 0.5) B)``).
2. The kernel ``D = softmax(-c ||p - T||)`` over the nine, ``c`` its sharpness (``sharpness``; the paper
   prints ``+c``; the nearest adjustment must get the largest weight).
3. Aggregation ``C`` (Comment 1): an entry of ``D`` counts as 1 when it exceeds
   1/2 and as 0 otherwise (the paper's "c large enough"); each output cell takes
   the ``rmin`` of the points whose kernel selects it. With a finite ``c`` a
   point within about ``1/c`` metres of a block boundary selects nothing and
   disappears; as ``c`` grows the output converges to the fast path's.
4. The inverse reshape restores the full-resolution screen for the next zoom.

At the loss zoom the landing adjustment of each point is read off the same
grids: the nearest one (``argmax D``; the backward "removes the role of the
kernel"); the dynamic gradient flow itself is :func:`~sdm.mapping.flow.dynamic_flow`,
the one rule every path shares.

Every tensor is created on the device of ``points``.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

from ..camera import Camera
from ..errors import SDMInputError
from ..representation import NO_RANK, inside
from ..zoom import depth_to_space, space_to_depth
from .flow import WINDOW_OFFSETS, dynamic_flow, window_offsets
from .result import MappingResult


def dense_mapping(
    points: torch.Tensor,
    pixels: torch.Tensor,
    config: torch.Tensor,
    rank: torch.Tensor,
    target: torch.Tensor,
    s: int,
    zoom: int,
    camera: Camera,
    sharpness: float = 1e9,
) -> MappingResult:
    """Grid-formulation SDM over the zooms ``s..zoom``; same contract as :func:`~sdm.mapping.fast.fast_mapping`.

    Args:
        points, pixels, config, rank, target, s, zoom, camera: as in
            :func:`~sdm.mapping.fast.fast_mapping`; each configuration must hold
            at most one point per pixel (a proper 2D representation).
        sharpness: the kernel's sharpness, the paper's ``c`` in ``softmax(-c ||p - T||)``, 1/metres.

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
        "id": _scatter(cell, torch.arange(n_points, device=points.device), n_configs, camera, -1),
        "rank": _scatter(cell, rank, n_configs, camera, NO_RANK),
    }
    device = points.device
    for at in range(s, zoom - 1, -1):  # each zoom, coarsest first
        sub = {name: space_to_depth(values, at) for name, values in grid.items()}
        active = sub["id"] >= 0  # (n, S, h, w)
        adjustments = _adjustments(sub["z"], at, camera)  # (n, S, 9, h, w, 2) metres
        offset = torch.stack((sub["x"], sub["y"]), -1)[:, :, None] - adjustments  # p - T
        distance = offset.norm(dim=-1)  # (n, S, 9, h, w)
        kernel = torch.softmax(-sharpness * distance, dim=2)
        selected = (kernel > 0.5) & active[:, :, None]
        if at == zoom:
            # Each point's input block and landing block (the nearest adjustment, argmax D) at the loss zoom.
            present = active.nonzero()  # (p, 4): configuration, sub-representation, block row, block col
            ids = sub["id"][active]
            nearest = kernel.argmax(2)[active]  # (p,) index into the 3x3 window
            entered_block = present[:, 2:]
            entered_landing = entered_block + window_offsets(device).index_select(0, nearest)
        sub = _aggregate(sub, selected)
        grid = {name: depth_to_space(values, at) for name, values in sub.items()}

    out_pixels = torch.full((n_points, 2), -1, dtype=torch.int64, device=device)
    out_id = grid["id"]
    where = (out_id >= 0).nonzero()
    out_pixels[out_id[out_id >= 0]] = where[:, 1:]
    entered = torch.zeros(n_points, dtype=torch.bool, device=device)
    entered[ids] = True
    block = torch.zeros(n_points, 2, dtype=torch.int64, device=device)
    landing = torch.zeros(n_points, 2, dtype=torch.int64, device=device)
    block[ids], landing[ids] = entered_block, entered_landing
    landed = entered & inside(landing, *target.shape[1:])
    flow, loss, matched = dynamic_flow(camera.project(points), points[:, 2], config, landed, block, landing, target,
                                       zoom, camera)
    return MappingResult(out_pixels, flow, loss, entered, matched, zoom, landed)


def _scatter(cell, values, n_configs, camera, empty):
    height, width = camera.screen_shape
    grid = torch.full((n_configs * height * width,), empty, dtype=values.dtype, device=values.device)
    grid[cell] = values
    return grid.view(n_configs, height, width)


def _adjustments(depth: torch.Tensor, zoom: int, camera: Camera) -> torch.Tensor:
    """XY-adjustments ``T`` at zoom ``zoom``: ``(n, S, 9, h, w, 2)`` (x, y) in metres at each cell's depth."""
    block_size = 1 << zoom
    h, w = depth.shape[-2:]
    rows = torch.arange(h, dtype=depth.dtype, device=depth.device)[:, None].expand(h, w)
    cols = torch.arange(w, dtype=depth.dtype, device=depth.device)[None, :].expand(h, w)
    safe_depth = torch.where(depth > 0, depth, torch.ones_like(depth))  # inactive cells: any valid depth
    adjustments = []
    for dk, dl in WINDOW_OFFSETS:
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
    for index, (dk, dl) in enumerate(WINDOW_OFFSETS):
        chosen = _shift(selected[:, :, index], dk, dl, False)
        shifted = {name: _shift(values, dk, dl, 0) for name, values in sub.items()}
        candidates_z.append(torch.where(chosen, shifted["z"], torch.inf))
        candidates_rank.append(torch.where(chosen, shifted["rank"], NO_RANK))
        sources.append(shifted)
    z = torch.stack(candidates_z, 2)  # (n, S, 9, h, w)
    nearest = z.min(2, keepdim=True).values
    rank = torch.where((z == nearest) & torch.isfinite(z), torch.stack(candidates_rank, 2), NO_RANK)
    best = rank.argmin(2, keepdim=True)
    occupied = torch.isfinite(nearest).squeeze(2)
    out = {}
    for name, empty in (("x", 0.0), ("y", 0.0), ("z", 0.0), ("id", -1), ("rank", NO_RANK)):
        stacked = torch.stack([source[name] for source in sources], 2)
        out[name] = torch.where(occupied, stacked.gather(2, best).squeeze(2), empty)
    return out


"""The paired runs' noise in one pass: the binding of ``sdm_noise_fill`` (``kernel/noise.c``), beside :mod:`sdm.sky`.

The library is built and loaded by :mod:`sdm.mapping.build`. The binding takes every array by keyword and checks
each one's dtype, shape, device and contiguity before the ctypes call (:func:`sdm.mapping.build.check_arrays`).
"""
from __future__ import annotations

import torch

from .errors import SDMInputError
from .mapping.build import check_arrays, library


def noise_fill(*, active: torch.Tensor, moves: torch.Tensor, out: torch.Tensor, written: torch.Tensor,
               n_written: int) -> int:
    """:func:`sdm.sky.add_target_noise`'s scatter into a reused buffer (``sdm_noise_fill``), in one pass.

    Args:
        active: ``(K, d)`` int64 active pixels: ``d - 2`` leading indices, then ``(row, col)``.
        moves: ``(K, 2)`` int64 the drawn moves ``(row, col)``.
        out: ``(..., H, W)`` bool buffer (``d - 2`` leading dimensions) whose only set entries are the
            ``n_written`` flat indices in ``written`` (all of it 0 where ``n_written`` is 0); pixels moved off
            its ``H x W`` grid are dropped.
        written: ``(>= K,)`` int64: in, those flat indices; out, this draw's.
        n_written: how many entries of ``written`` hold the last draw's indices.

    All on the CPU, C-contiguous. Returns the number of pixels now set (this draw's ``n_written``).

    Raises:
        SDMInputError: naming the first argument of the wrong dtype, shape, device or layout.
    """
    sizes = check_arrays("noise_fill", active=(active, torch.int64, ("K", "d")), moves=(moves, torch.int64, ("K", 2)),
                         out=(out, torch.bool, None), written=(written, torch.int64, ("W",)))
    if sizes["d"] < 2 or out.dim() != sizes["d"]:
        raise SDMInputError(f"noise_fill: out must have {sizes['d']} dimensions (active's columns: leading indices, "
                            f"then row and column), got shape {tuple(out.shape)}")
    if sizes["W"] < sizes["K"] or not 0 <= int(n_written) <= sizes["W"]:
        raise SDMInputError(f"noise_fill: written must hold at least the {sizes['K']} active pixels and n_written "
                            f"({n_written}) of them, got {sizes['W']}")
    height, width = out.shape[-2:]
    # on out's device (the CPU), never device-less: under torch.set_default_device that would not be memory
    lead_strides = torch.tensor(out.stride()[:-2] or (0,), dtype=torch.int64, device=out.device)
    return int(library().sdm_noise_fill(sizes["K"], active.data_ptr(), sizes["d"] - 2, lead_strides.data_ptr(),
                                        moves.data_ptr(), height, width, out.data_ptr(), written.data_ptr(),
                                        int(n_written)))

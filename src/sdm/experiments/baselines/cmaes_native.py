"""The CMA-ES baseline's compiled count: ``sdm_pixel_mismatch`` (``kernel/mismatch.c``)'s binding, beside :mod:`.cmaes`.

The library is built and loaded by :mod:`sdm.mapping.build`. The binding takes every array by keyword and checks
each one's dtype, shape, device and contiguity before the ctypes call (:func:`sdm.mapping.build.check_arrays`):
the C function reads raw pointers, so a swapped or mistyped array would be read as something else.
"""
from __future__ import annotations

import torch

from ...errors import SDMInputError
from ...mapping.build import check_arrays, eager_under_compile, library


@eager_under_compile
def pixel_mismatch(*, thetas: torch.Tensor, gain: torch.Tensor, frac_bounds: torch.Tensor, shift_low: torch.Tensor,
                   shift_high: torch.Tensor, group_start: torch.Tensor, config_group: torch.Tensor,
                   cells: torch.Tensor, table: torch.Tensor, padded_shape: tuple[int, int], limits: torch.Tensor,
                   n_target: int, memo_offsets: torch.Tensor, memo_sums: torch.Tensor, memo_state: torch.Tensor,
                   stamp: torch.Tensor) -> torch.Tensor:
    """The exact zoom-0 pixel mismatch of ``K`` candidates in one pass over the points (``sdm_pixel_mismatch``).

    The arrays of a :class:`~sdm.experiments.baselines.mismatch.ShiftLayout` of ``P`` points in ``G`` rigid groups over ``N``
    configurations, its compact table and a :class:`~sdm.experiments.baselines.mismatch.MismatchMemo` of ``L >= K`` slots; all
    on the CPU, C-contiguous.

    Args:
        thetas: ``(K, 2)`` float64 candidates ``(a, b)``, metres.
        gain: ``(G, 2)`` float64 pixels per metre (row per b, col per a) of each group.
        frac_bounds: ``(2, G, 2)`` float64 each group's lowest and highest sub-pixel offset, widened by the margin.
        shift_low, shift_high: ``(G, 2)`` float64 the clamp range of each group's whole shift.
        group_start: ``(G + 1,)`` int64 the first point of each group; ``config_group``: ``(N + 1,)`` int64 the
            first group of each configuration.
        cells: ``(P,)`` int32 each point's padded pixel at theta = 0, within its configuration.
        table: ``(N * Hp * Wp,)`` int8 weight + 1 per padded pixel (:meth:`ShiftLayout.table` with ``compact``).
        padded_shape: ``(Hp, Wp)``, the padded screen.
        limits: ``(3,)`` float64 the largest ``|gain|`` (row, col) and the range up to which shifts are trusted.
        n_target: active target pixels of the run.
        memo_offsets, memo_sums, memo_state: ``(L * G,)``, ``(L * N,)``, ``(L + 1,)`` int64, the memo's
            last candidates (their group shifts, per-configuration sums, validity and next slot).
        stamp: ``(Hp * Wp + 1,)`` int32 scratch (uint32 to the C code), zero at first.

    Returns:
        ``(K,)`` int64 counts (false positives + false negatives), ``-1`` for a candidate whose group shifts
        cannot be trusted (the caller counts it by the torch reference).

    Raises:
        SDMInputError: naming the first argument of the wrong dtype, shape, device or layout, or a memo of fewer
            than ``K`` slots.
    """
    padded_height, padded_width = (int(side) for side in padded_shape)
    cells_per_config = padded_height * padded_width
    sizes = check_arrays(
        "pixel_mismatch", thetas=(thetas, torch.float64, ("K", 2)), gain=(gain, torch.float64, ("G", 2)),
        frac_bounds=(frac_bounds, torch.float64, (2, "G", 2)), shift_low=(shift_low, torch.float64, ("G", 2)),
        shift_high=(shift_high, torch.float64, ("G", 2)), group_start=(group_start, torch.int64, ("G+1",)),
        config_group=(config_group, torch.int64, ("N+1",)), cells=(cells, torch.int32, ("P",)),
        table=(table, torch.int8, (f"N*{cells_per_config}",)), limits=(limits, torch.float64, (3,)),
        memo_state=(memo_state, torch.int64, ("L+1",)), memo_offsets=(memo_offsets, torch.int64, ("L*G",)),
        memo_sums=(memo_sums, torch.int64, ("L*N",)), stamp=(stamp, torch.int32, (cells_per_config + 1,)))
    n_candidates, n_slots = sizes["K"], sizes["L"]
    if n_slots < n_candidates:
        raise SDMInputError(f"pixel_mismatch: memo_state holds {n_slots} slots, fewer than the {n_candidates} "
                            "candidates")
    counts = torch.empty(n_candidates, dtype=torch.int64, device=thetas.device)  # never device-less
    library().sdm_pixel_mismatch(
        n_candidates, thetas.data_ptr(), sizes["G"], sizes["N"], gain.data_ptr(), frac_bounds.data_ptr(),
        shift_low.data_ptr(), shift_high.data_ptr(), group_start.data_ptr(), config_group.data_ptr(),
        cells.data_ptr(), table.data_ptr(), cells_per_config, padded_width, limits.data_ptr(), int(n_target), n_slots,
        memo_offsets.data_ptr(), memo_sums.data_ptr(), memo_state.data_ptr(), stamp.data_ptr(), counts.data_ptr())
    return counts

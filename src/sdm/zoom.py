"""Zoom levels: the space-to-depth reshape and zoomed-out targets (paper, section 6.1; docs/method/paper.md, Forward pass).

One reshape step turns an ``h x w`` representation into four ``(h/2) x (w/2)``
ones, each holding the pixels of one parity of ``(row, col)`` (the paper's
pseudo-code: row-major ``reshape`` to ``(h/2, 2, w/2, 2)``, ``permute`` to
``(2, 2, h/2, w/2)``, split). After ``k`` steps there are ``4^k``
sub-representations of ``(h/B) x (w/B)``, ``B = 2^k``; pixel ``(r, c)`` sits in
the sub-representation of *phase* ``(r mod B, c mod B)`` at *block*
``(r div B, c div B)``.
"""
from __future__ import annotations

import torch

from .errors import SDMInputError


def check_divisible(shape: tuple[int, int], steps: int) -> None:
    """Raise :class:`SDMInputError` unless both screen sides are divisible by ``2**steps``."""
    if int(steps) != steps or steps < 0:
        raise SDMInputError(f"the coarsest zoom s must be a non-negative integer, got {steps!r}")
    block = 1 << steps
    height, width = shape
    if height % block or width % block:
        raise SDMInputError(
            f"screen size {height} x {width} is not divisible by 2^s = {block} (s = {steps}); "
            f"choose s <= {min((height & -height), (width & -width)).bit_length() - 1}"
        )


def space_to_depth(x: torch.Tensor, steps: int = 1) -> torch.Tensor:
    """Apply the paper's reshape ``steps`` times.

    Args:
        x: ``(..., h, w)`` representations, ``h`` and ``w`` divisible by ``2**steps``.
        steps: number of reshape steps ``k``.

    Returns:
        ``(..., 4**k, h / 2**k, w / 2**k)`` sub-representations. Index
        ``t = sum_i (2 p_i + q_i) 4^(k-1-i)`` holds the pixels whose row has
        bit ``i`` equal to ``p_i`` and whose column has bit ``i`` equal to
        ``q_i`` (:func:`subrep_phases` lists the phase of every index).
    """
    check_divisible(tuple(x.shape[-2:]), steps)
    x = x.unsqueeze(-3)
    for _ in range(steps):
        *lead, subreps, h, w = x.shape
        # Row-major (h/2, 2, w/2, 2), parity axes moved in front of the grid, then split into 4.
        x = x.reshape(*lead, subreps, h // 2, 2, w // 2, 2)
        x = x.permute(*range(len(lead)), -5, -3, -1, -4, -2)
        x = x.reshape(*lead, subreps * 4, h // 2, w // 2)
    return x


def depth_to_space(x: torch.Tensor, steps: int = 1) -> torch.Tensor:
    """Inverse of :func:`space_to_depth`: ``(..., 4**k, h, w)`` -> ``(..., h 2**k, w 2**k)``."""
    if x.ndim < 3 or x.shape[-3] % (4**steps):
        raise SDMInputError(f"expected (..., 4^{steps}, h, w) sub-representations, got {tuple(x.shape)}")
    for _ in range(steps):
        *lead, subreps, h, w = x.shape
        x = x.reshape(*lead, subreps // 4, 2, 2, h, w)
        x = x.permute(*range(len(lead)), -5, -2, -4, -1, -3)
        x = x.reshape(*lead, subreps // 4, h * 2, w * 2)
    return x.squeeze(-3)


def subrep_phases(steps: int, device: torch.device | str | None = None) -> torch.Tensor:
    """``(4**k, 2)`` int64 phase ``(row mod 2^k, col mod 2^k)`` of each sub-representation index, on ``device``."""
    grid = torch.arange(1 << steps, device=device)
    rows, cols = torch.meshgrid(grid, grid, indexing="ij")
    phases = torch.stack((rows, cols), dim=-1)  # (B, B, 2): a B x B screen whose pixel (r, c) is its own phase
    return space_to_depth(phases.permute(2, 0, 1), steps).reshape(2, -1).T.contiguous()


def zoom_out(target: torch.Tensor, steps: int) -> torch.Tensor:
    """Zoomed-out target: the union of the ``4**k`` sub-representations (``B x B`` max-pool).

    Args:
        target: ``(..., H, W)`` bool, on any device.

    Returns:
        ``(..., H / 2**k, W / 2**k)`` bool, contiguous, on the same device.
    """
    check_divisible(tuple(target.shape[-2:]), steps)
    for _ in range(steps):
        target = _halve(target)
    return target


def target_pyramid(target: torch.Tensor, steps: int) -> list[torch.Tensor]:
    """Zoomed-out targets at zooms ``0..steps``: element ``k`` is ``(..., H / 2**k, W / 2**k)`` bool.

    Each zoom's is the ``2 x 2`` max-pool of the one before (a ``B x B`` block is active when one of
    its four ``B/2 x B/2`` quarters is: exact for bools). Zoom 0's is ``target`` itself.
    """
    check_divisible(tuple(target.shape[-2:]), steps)
    pyramid = [target]
    for _ in range(steps):
        pyramid.append(_halve(pyramid[-1]))
    return pyramid


def _halve(target: torch.Tensor) -> torch.Tensor:
    """``2 x 2`` any-pool of ``(..., h, w)`` bool (``h``, ``w`` even; the caller checked): ``(..., h/2, w/2)``.

    Two elementwise ORs over strided views (row pairs, then column pairs) instead of a search for
    the active pixels or an ``any`` reduction: 4.7 ms for a whole pyramid of 512 x 128 x 256 targets
    (s = 4) against 23 ms for the ``nonzero`` scatter it replaced (one thread; torch's ``any`` over
    the block axes was 19 ms).
    """
    *lead, height, width = target.shape
    pairs = target.reshape(*lead, height // 2, 2, width)
    rows = pairs[..., 0, :] | pairs[..., 1, :]  # (..., h/2, w), contiguous
    cols = rows.reshape(*lead, height // 2, width // 2, 2)
    return cols[..., 0] | cols[..., 1]

"""What one pass of the SDM layer produces, whichever implementation ran it."""
from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class MappingResult:
    """Forward output and dynamic gradient flow of the SDM chain (zooms ``s..zoom``).

    Attributes:
        out_pixels: ``(P, 2)`` int64 pixel ``(row, col)`` of each point in the
            output representation ``L~`` (full resolution: block * 2^zoom + phase);
            ``-1`` for points dropped (off the grid, or hidden by ``rmin``).
        flow: ``(P, 2)`` float64 ``dJ/d(x, y)`` per point (dimensionless: sums of
            signs), zero for matched points and points dropped before the loss zoom.
        loss: ``()`` float64 ``J``: over unmatched points, the summed L1 distance in
            metres (x and y) to the XY-adjustments of the active target blocks in
            their 3x3 window.
        entered: ``(P,)`` bool, the point reached the loss zoom.
        matched: ``(P,)`` bool, the point's landing block is active in the zoomed-out target.
        zoom: the loss zoom (the finest).
        landed: ``(P,)`` bool, the point entered the loss zoom and its landing block is on
            the grid (points leaving the screen are neither matched nor pulled).
    """

    out_pixels: torch.Tensor
    flow: torch.Tensor
    loss: torch.Tensor
    entered: torch.Tensor
    matched: torch.Tensor
    zoom: int
    landed: torch.Tensor

    @property
    def missed(self) -> torch.Tensor:
        """``(P,)`` bool, landed on the grid in a block the target leaves empty (these are pulled)."""
        return self.landed & ~self.matched

    @property
    def alive(self) -> torch.Tensor:
        """``(P,)`` bool, the point is in the output representation."""
        return self.out_pixels[:, 0] >= 0

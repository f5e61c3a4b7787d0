"""The depth flow inside the layer: :class:`DepthPull` injects ``dJ/dz`` into autograd (:func:`depth_flow`), for
the general shift ``theta = (a, b, c)`` (beyond the paper; the derivation: :mod:`sdm.depth`, docs/method/depth.md).
"""
from __future__ import annotations

import torch


class DepthPull(torch.autograd.Function):
    """``0 = DepthPull(points, flow)``: a zero loss term whose gradient on ``z`` is the depth flow.

    Args (forward):
        points: ``(P, 3)`` float camera-frame points, metres, ``z > 0`` (differentiable).
        flow: ``(P, 2)`` the points' ``(x, y)`` flow (sums of signs, non-differentiable), dtype of ``points``.

    Returns ``()`` zero of the dtype and device of ``points``; backward gives
    ``(P, 3)`` ``(0, 0, -(flow_x x + flow_y y) / z)`` times the incoming gradient
    (the ``x``/``y`` parts already come from the layer's own backward).
    """

    @staticmethod
    def forward(points, flow):
        return points.new_zeros(())

    @staticmethod
    def setup_context(ctx, inputs, output):
        points, flow = inputs
        ctx.save_for_backward(points.detach(), flow)

    @staticmethod
    def backward(ctx, grad):
        points, flow = ctx.saved_tensors
        return grad * torch.nn.functional.pad(depth_flow(points, flow)[:, None], (2, 0)), None


def depth_flow(points: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
    """``(P,)`` ``dJ/dz = -(flow_x x + flow_y y) / z`` (dimensionless, dtype of ``points``).

    Args:
        points: ``(P, 3)`` camera-frame points in metres (x right, y down, z forward, ``z > 0``).
        flow: ``(P, 2)`` their ``(x, y)`` flow.
    """
    x, y, z = points.unbind(-1)
    return -(flow[:, 0] * x + flow[:, 1] * y) / z

"""Depth: the general shift ``theta = (a, b, c)`` (beyond the paper; docs/method/depth.md).

The paper's flow pulls a point's ``x`` and ``y`` by the signs of its screen
offsets to the target blocks pulling it; it gives ``z`` nothing. The same pixel
evidence says how ``z`` should move: at depth ``z`` a point projects to
``u = f_x x / z + c_x`` (and ``v`` likewise), so ``du/dz = -(u - c_x) / z`` -- a
change of depth moves the projection *radially*, towards the principal point
when ``z`` grows. With the paper's loss measured in metres at the point's depth,
``J_x = |u - T_u| z / f_x`` at a fixed scale, the chain rule gives

    dJ/dz = sign(u - T_u) * (-f_x x / z^2) * (z / f_x) + (same for y)
          = -(flow_x * x + flow_y * y) / z,

where ``flow_x, flow_y`` are the point's summed signs (its eq. 19 flow, or any
rule of :data:`sdm.FLOW_RULES`). A point whose target lies radially outside it
(``flow`` pointing away from the axis) is pulled nearer (``dJ/dz > 0``: SGD
decreases ``z``, which enlarges ``|u - c_x|``). :class:`DepthPull` injects this
``z`` gradient into autograd without changing the loss value.
"""
from __future__ import annotations

import torch

from .mapping.depth_flow import DepthPull, depth_flow
from .sky import shifted_target

__all__ = ["DepthPull", "depth_flow", "depth_targets"]


def depth_targets(data, shift, camera=None) -> torch.Tensor:
    """``(N, H, W)`` bool targets of a :class:`~sdm.batch.ConfigurationSet`'s points moved by ``shift = (a, b, c)``.

    The same construction as :func:`sdm.sky.build_configuration` (``shifted_target``
    of the configuration's points), for an existing set, e.g. a Sky file built
    with a 2D shift.
    """
    camera = camera or data.camera
    offsets = data.offsets.tolist()
    return torch.stack([shifted_target(data.points[start:stop], tuple(shift), camera)
                        for start, stop in zip(offsets[:-1], offsets[1:])])

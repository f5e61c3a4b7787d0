"""The SDM layer: a torch autograd function whose backward is the dynamic gradient flow.

Use :class:`SpatialDomainMapping` as a module in any PyTorch model: give it the
(differentiable) 3D points of a proper 2D representation, the pixel each point
sits in, and the binary target; its ``loss`` back-propagates the dynamic
gradient flow to the points, and autograd carries it to whatever produced them
(in the Sky problem, the shift ``theta``)::

    layer = SpatialDomainMapping(s=4, zoom=0)
    out = layer(q + sdm.sky.shift_vector(theta, q), pixels, target)   # theta (2,) -> (a, b, 0)
    out.loss.backward()          # theta.grad: the summed pulls on (x, y)
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from ..camera import APOLLO_CAMERA_5, Camera, check_points
from ..errors import SDMInputError
from ..representation import inside, priority_rank
from ..zoom import check_divisible, zoom_out
from .dense import dense_mapping
from .depth_flow import DepthPull
from .fast import fast_mapping
from .result import MappingResult
from .flow import dynamic_flow
from .rules import RULES

METHODS = {"fast": fast_mapping, "dense": dense_mapping}

#: Point dtypes the layer accepts: screen coordinates need at least float32's 24-bit mantissa.
POINT_DTYPES = (torch.float32, torch.float64)


class SDMFunction(torch.autograd.Function):
    """``J = SDM(points)``: forward runs the chain, backward returns the dynamic gradient flow.

    The flow is not the derivative of a smooth function of the points: it is
    the paper's eq. 19 (:func:`~sdm.mapping.flow.dynamic_flow`), the summed sign
    pulls of the unmatched points towards their active target adjustments. Its
    z component is zero (c is ignored).

    Written as ``forward`` + ``setup_context`` (no ``ctx`` in the forward), so that
    ``torch.func`` transforms such as :func:`torch.func.grad` can see it. Outputs
    (all on the device of ``points``): ``loss`` ``()`` (differentiable, metres),
    then, marked non-differentiable, ``flow`` ``(P, 2)`` (dtype of ``points``),
    ``out_pixels`` ``(P, 2)`` int64, ``entered``, ``matched``, ``landed`` ``(P,)`` bool
    (see :class:`~sdm.mapping.result.MappingResult`).
    """

    @staticmethod
    def forward(points, pixels, config, rank, target, s, zoom, camera, method, options):
        result = METHODS[method](points.detach(), pixels, config, rank, target, s, zoom, camera, **options)
        return (result.loss.to(points.dtype), result.flow.to(points.dtype), result.out_pixels, result.entered,
                result.matched, result.landed)

    @staticmethod
    def setup_context(ctx, inputs, output):
        _, flow, *masks = output
        ctx.mark_non_differentiable(flow, *masks)
        ctx.save_for_backward(flow)

    @staticmethod
    def backward(ctx, grad_loss, *_no_gradient):
        (flow,) = ctx.saved_tensors
        return (grad_loss * F.pad(flow, (0, 1)),) + (None,) * 9


@dataclass
class SDMOutput:
    """What the layer returns.

    Attributes:
        loss: ``()`` differentiable loss ``J`` (metres); its gradient is the dynamic flow.
        result: the full :class:`~sdm.mapping.result.MappingResult` (output
            pixels, flow, matched points).
        num_configs: number of configurations ``n`` in the batch.
        camera: camera and screen.
        config: ``(P,)`` configuration index of each point.
        depth: ``(P,)`` depth of each point, metres.
    """

    loss: torch.Tensor
    result: MappingResult
    num_configs: int
    camera: Camera
    config: torch.Tensor
    depth: torch.Tensor

    def depth_map(self) -> torch.Tensor:
        """``(n, H, W)`` the output representation ``L~`` as depth (metres), 0 where empty."""
        height, width = self.camera.screen_shape
        image = torch.zeros(self.num_configs, height, width, dtype=self.depth.dtype, device=self.depth.device)
        alive = self.result.alive
        pixels = self.result.out_pixels[alive]
        image[self.config[alive], pixels[:, 0], pixels[:, 1]] = self.depth[alive]
        return image

    def occupancy(self) -> torch.Tensor:
        """``(n, H / 2^zoom, W / 2^zoom)`` bool: the zoomed-out binary mask of ``L~``."""
        return zoom_out(self.depth_map() > 0, self.result.zoom)


class SpatialDomainMapping(nn.Module):
    """Spatial Domain Mapping with the zoom chain (zooms ``s..zoom``) as a module.

    Args:
        camera: camera and screen (default ApolloCar3D ``Camera_5``, 128 x 256).
        s: the coarsest zoom; both screen sides must be divisible by ``2^s``.
        zoom: the finest zoom, whose output is compared with the zoomed-out target.
        method: ``"fast"`` (point rows) or ``"dense"`` (the paper's grids, for reference).
        sharpness: the dense path's kernel sharpness, the paper's ``c``, 1/metres (ignored by ``"fast"``,
            which is the ``c -> infinity`` limit).
        rule: the gradient rule: a name of :data:`sdm.mapping.rules.RULES` (default ``"paper"``, eq. 19), a
            :class:`~sdm.mapping.rules.Rule`, or a function with :func:`~sdm.mapping.flow.dynamic_flow`'s
            signature; only ``"paper"`` with ``method="dense"``.
        fit_depth: also give ``z`` a gradient, the depth flow of :mod:`sdm.depth`
            (beyond the paper; default off: ``z`` gets none, as in the paper).

    >>> import torch
    >>> from sdm import SKY_SHIFT, ConfigurationSet, build_configuration
    >>> centres = torch.tensor([[-3.0, 2.5, 20.0], [2.0, 3.0, 35.0], [6.0, 4.5, 60.0]], dtype=torch.float64)
    >>> batch = ConfigurationSet.from_configurations([build_configuration(centres, shift=SKY_SHIFT)]).batch([0])
    >>> theta = torch.zeros(2, dtype=torch.float64, requires_grad=True)  # the shift (a, b), metres
    >>> layer = SpatialDomainMapping(s=4, zoom=0)
    >>> out = layer(batch.points + torch.nn.functional.pad(theta, (0, 1)), batch.pixels, batch.targets, batch.config)
    >>> out.loss.backward()
    >>> theta.grad  # the summed pulls: a step against them moves theta towards SKY_SHIFT = (0.517, 0.303)
    tensor([-46., -38.], dtype=torch.float64)
    >>> SpatialDomainMapping(rule="closed_centred_r1").rule
    Rule('closed_centred_r1', compiled=CENTRED)
    """

    def __init__(self, camera: Camera = APOLLO_CAMERA_5, s: int = 4, zoom: int = 0, method: str = "fast", sharpness: float = 1e9,
                 rule="paper", fit_depth: bool = False):
        super().__init__()
        check_divisible(camera.screen_shape, s)
        if int(zoom) != zoom or not 0 <= zoom <= s:
            raise SDMInputError(f"zoom must be an integer in [0, s] = [0, {s}], got {zoom!r}")
        if method not in METHODS:
            raise SDMInputError(f"method must be one of {sorted(METHODS)}, got {method!r}")
        if not sharpness > 0:
            raise SDMInputError(f"sharpness (the dense kernel's c) must be positive, got {sharpness!r}")
        self.camera, self.s, self.zoom, self.method = camera, int(s), int(zoom), method
        self.sharpness = float(sharpness)
        self.rule = RULES.resolve(rule)
        self.flow_rule = self.rule.flow  # dynamic_flow itself for "paper": the kernel's flow (fast_mapping)
        self.fit_depth = bool(fit_depth)
        if method == "dense" and self.flow_rule is not dynamic_flow:
            raise SDMInputError(f"rule: the dense reference implements only the paper's rule, got {rule!r}")

    def forward(
        self,
        points: torch.Tensor,
        pixels: torch.Tensor,
        target: torch.Tensor,
        config: torch.Tensor | None = None,
        rank: torch.Tensor | None = None,
        target_is_zoomed: bool = False,
        validate: bool = True,
    ) -> SDMOutput:
        """Map shifted points and measure them against the target.

        Every tensor argument must live on the device of ``points`` (any device);
        the outputs live there too.

        Args:
            points: ``(P, 3)`` float32 or float64 points ``rinv(I~)`` in metres, ``z > 0``;
                differentiable (usually ``Q + theta``).
            pixels: ``(P, 2)`` int64 ``(row, col)`` pixel each point sits in (its
                pixel in ``I~``; the shift moves the point, not its pixel).
            target: ``(n, H, W)`` or ``(H, W)`` bool target ``L`` (or, with
                ``target_is_zoomed``, the ``(n, H / 2^zoom, W / 2^zoom)`` zoomed-out one).
            config: ``(P,)`` int64 configuration of each point in ``[0, n)``; may be
                omitted only for a single target (``n = 1``).
            rank: ``(P,)`` int64 ``rmin`` priority; default: depth, then row order.
            target_is_zoomed: ``target`` is already zoomed out to zoom ``zoom``.
            validate: check every input's values too (the default). Only callers that checked
                their inputs once up front (the trainer, on a packed set) turn this off; the
                types, shapes and devices are checked either way.

        Returns:
            :class:`SDMOutput`.

        Raises:
            SDMInputError: naming the argument, for a wrong shape, dtype or device,
                points behind the camera or non-finite, pixels off the screen,
                configuration indices out of range, or a missing ``config`` with
                several targets.
        """
        if target.ndim == 2:
            target = target[None]
        self._check(points, pixels, target, config, rank, target_is_zoomed, values=validate)
        if config is None:
            config = torch.zeros(points.shape[0], dtype=torch.int64, device=points.device)
        if rank is None:
            rank = priority_rank(points.detach()[:, 2])
        zoomed = target if target_is_zoomed else zoom_out(target, self.zoom)
        options = {"sharpness": self.sharpness} if self.method == "dense" else {"flow_rule": self.flow_rule}
        loss, flow, out_pixels, entered, matched, landed = SDMFunction.apply(
            points, pixels, config, rank, zoomed, self.s, self.zoom, self.camera, self.method, options
        )
        if self.fit_depth:  # a zero term whose gradient on z is the depth flow (sdm.depth)
            loss = loss + DepthPull.apply(points, flow)
        result = MappingResult(out_pixels, flow, loss.detach(), entered, matched, self.zoom, landed)
        return SDMOutput(loss, result, int(target.shape[0]), self.camera, config, points.detach()[:, 2])

    def _check(self, points, pixels, target, config, rank, target_is_zoomed, values: bool = True) -> None:
        """:class:`SDMInputError` naming the argument: types, dtypes, shapes, devices and the configurations'
        range always (the flows index the targets by configuration), and with ``values`` the points' finiteness
        and the pixels on the screen."""
        height, width = self.camera.screen_shape
        if not isinstance(points, torch.Tensor):
            raise SDMInputError(f"points must be a torch.Tensor, got {type(points).__name__}")
        if points.dtype not in POINT_DTYPES:
            raise SDMInputError(
                f"points must be float32 or float64 (float64 is the default), got {points.dtype}: "
                "half precision cannot place a point at 100 m to a screen pixel"
            )
        # Devices first: any later check would otherwise fail inside torch on a mixed-device op.
        for name, tensor in (("pixels", pixels), ("target", target), ("config", config), ("rank", rank)):
            if tensor is None:
                continue
            if not isinstance(tensor, torch.Tensor):
                raise SDMInputError(f"{name} must be a torch.Tensor, got {type(tensor).__name__}")
            if tensor.device != points.device:
                raise SDMInputError(
                    f"{name} is on {tensor.device} but points are on {points.device}: "
                    "every input of the layer must live on one device (move them with .to(device))"
                )
        if values:
            check_points(points, "points")
        if points.ndim != 2 or points.shape[-1] != 3:
            raise SDMInputError(f"points must have shape (P, 3), got {tuple(points.shape)}")
        n_points = points.shape[0]
        if n_points == 0:
            raise SDMInputError("points: the configuration is empty (no points to map)")
        if target.dtype != torch.bool:
            raise SDMInputError(f"target must be a bool mask, got {target.dtype}")
        expected = (height >> self.zoom, width >> self.zoom) if target_is_zoomed else (height, width)
        if target.ndim != 3 or tuple(target.shape[1:]) != expected:
            raise SDMInputError(f"target must have shape (n, {expected[0]}, {expected[1]}), got {tuple(target.shape)}")
        if pixels.shape != (n_points, 2) or pixels.dtype != torch.int64:
            raise SDMInputError(f"pixels must be int64 of shape ({n_points}, 2), got {pixels.dtype} {tuple(pixels.shape)}")
        if values and not bool(inside(pixels, height, width).all()):
            raise SDMInputError(f"pixels must lie on the {height} x {width} screen")
        n_configs = int(target.shape[0])
        if config is None:
            if n_configs > 1:
                raise SDMInputError(
                    f"config is required: target holds {n_configs} targets, and without config every point "
                    "would be compared with target 0"
                )
        else:
            if config.shape != (n_points,) or config.dtype != torch.int64:
                raise SDMInputError(f"config must be int64 of shape ({n_points},), got {config.dtype} {tuple(config.shape)}")
            if not 0 <= int(config.min()) <= int(config.max()) < n_configs:  # indexes the targets: always
                raise SDMInputError(f"config must hold indices into the {n_configs} targets, got "
                                    f"{int(config.min())}..{int(config.max())}")
        if rank is not None and (rank.shape != (n_points,) or rank.dtype != torch.int64):
            raise SDMInputError(f"rank must be int64 of shape ({n_points},), got {rank.dtype} {tuple(rank.shape)}")

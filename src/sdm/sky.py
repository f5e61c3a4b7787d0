"""Sky configurations: from one image's car centres to the points ``Q`` and the target ``L``.

Construction (paper, section 3 and appendix A; docs/method/paper.md, Geometry):

1. ``E``: fragments ``(car centre, r = z)`` rendered with ``rmin``; cars behind
   the camera or off screen are dropped.
2. ``E'`` ("circles"): every active pixel of ``E`` paints the on-screen pixels
   within ``exp(-d/3) >= 0.25`` (``d <= 3 ln 4``, 57 pixels) with its value,
   keeping the minimum where circles overlap.
3. ``Q``: one point per active pixel of ``E'``: the back-projection of the
   pixel centre at depth ``E'``. Each pixel holds exactly one point.
   The point belongs to the car whose circle gave it its depth (the ``rmin``
   winner: the nearest car; of cars at equal depth, the one listed first in
   ``E``'s row-major order). A car whose on-screen disc nearer circles cover
   entirely owns no point.
4. ``L``: occupancy of ``floor(P(Q + (a, b, 0)))``; points leaving the screen
   are dropped.

The solver sees ``Q`` (equivalently ``E'``) and ``L``, never the shift.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import product

import torch
import torch.nn.functional as F

from .camera import APOLLO_CAMERA_5, Camera
from .errors import SDMInputError
from .mapping.build import serves
from .representation import first_by_rank, inside, occupancy, priority_rank, render_rmin, screen_pixels
from .sky_native import noise_fill

#: The shift of the Sky dataset, metres: theta* = (a, b).
SKY_SHIFT = (0.517, 0.303)

#: Circle radius in screen pixels: exp(-d/3) >= 0.25  <=>  d <= 3 ln 4.
CIRCLE_RADIUS = 3 * math.log(4)


@dataclass
class SkyConfiguration:
    """One configuration of the Sky dataset.

    Attributes:
        pixels: ``(K, 2)`` int64 active pixels ``(row, col)`` of ``E'``, row-major order.
        depth: ``(K,)`` float64 depth in metres of each active pixel (the value of ``E'``).
        target: ``(H, W)`` bool target ``L``.
        image_id: name of the source image.
        centres: ``(M, 2)`` int64 active pixels of ``E`` (car centres on screen), row-major order: the
            configuration's cars. Cars whose centres fall into one pixel of ``E`` are one car here
            (``rmin`` keeps the nearest).
        centre_depth: ``(M,)`` float64 values of ``E`` there.
        cars: ``(K,)`` int64 the car each point belongs to, an index into ``centres`` in ``[0, M)``: the
            car whose circle gave the point its depth (:func:`paint_circles`), so
            ``depth == centre_depth[cars]``. ``None`` for a configuration put together by hand
            without it.
    """

    pixels: torch.Tensor
    depth: torch.Tensor
    target: torch.Tensor
    image_id: str = ""
    centres: torch.Tensor = field(default_factory=lambda: torch.zeros(0, 2, dtype=torch.int64))
    centre_depth: torch.Tensor = field(default_factory=lambda: torch.zeros(0, dtype=torch.float64))
    cars: torch.Tensor | None = None

    @property
    def num_points(self) -> int:
        return int(self.pixels.shape[0])

    def points(self, camera: Camera = APOLLO_CAMERA_5) -> torch.Tensor:
        """``(K, 3)`` float64 points ``Q`` in metres (pixel centres back-projected)."""
        return pixel_centre_points(self.pixels, self.depth, camera)

    def circles(self, camera: Camera = APOLLO_CAMERA_5) -> torch.Tensor:
        """``(H, W)`` float64 representation ``E'`` (depth, 0 where empty)."""
        image = torch.zeros(camera.screen_shape, dtype=torch.float64, device=self.depth.device)
        image[self.pixels[:, 0], self.pixels[:, 1]] = self.depth
        return image


def circle_offsets(radius: float = CIRCLE_RADIUS) -> torch.Tensor:
    """``(n, 2)`` int64 offsets ``(drow, dcol)`` within ``radius`` screen pixels (57 for the default)."""
    reach = int(math.floor(radius))
    offsets = [(i, j) for i, j in product(range(-reach, reach + 1), repeat=2) if math.hypot(i, j) <= radius]
    return torch.tensor(offsets, dtype=torch.int64)


def render_centres(centres: torch.Tensor, camera: Camera = APOLLO_CAMERA_5) -> torch.Tensor:
    """The representation ``E``: car centres as fragments ``(c, r = z)`` with ``rmin``.

    Args:
        centres: ``(M, 3)`` car centres in metres (camera frame); cars with
            ``z <= 0`` (behind the camera) and cars off screen are dropped.

    Returns:
        ``(H, W)`` float64 depth of the nearest car centre per pixel, 0 where empty.
    """
    centres = _check_centres(centres)
    visible = centres[centres[:, 2] > 0]
    return render_rmin(visible, visible[:, 2], camera)


def draw_circles(centre_image: torch.Tensor, radius: float = CIRCLE_RADIUS) -> torch.Tensor:
    """The representation ``E'``: a disc of each active pixel's value, minimum where discs overlap.

    Args:
        centre_image: ``(H, W)`` representation ``E`` (0 = empty).

    Returns:
        ``(H, W)`` representation ``E'``, same dtype and device.
    """
    return paint_circles(centre_image, radius)[0]


def paint_circles(centre_image: torch.Tensor, radius: float = CIRCLE_RADIUS) -> tuple[torch.Tensor, torch.Tensor]:
    """The representation ``E'`` and, per pixel, the car whose circle painted it.

    Every active pixel of ``E`` (a car) paints the on-screen pixels of its disc with its value.
    Where discs overlap, the ``rmin`` rule picks the painter: the smallest value (the nearest car)
    wins; of cars with equal values the one listed first wins (row-major order of ``E``, the order
    of :attr:`SkyConfiguration.centres`). The winner's value is the minimum, so ``E'`` is the
    minimum of the overlapping values.

    Args:
        centre_image: ``(H, W)`` representation ``E`` (0 = empty).
        radius: disc radius in screen pixels.

    Returns:
        ``(circles, owner)``: ``(H, W)`` representation ``E'`` (dtype and device of ``centre_image``,
        0 where empty) and ``(H, W)`` int64 index of the painting car in ``centre_image.nonzero()``
        (``-1`` where empty).
    """
    height, width = centre_image.shape
    device = centre_image.device
    circles = torch.zeros(height * width, dtype=centre_image.dtype, device=device)
    owner = torch.full((height * width,), -1, dtype=torch.int64, device=device)
    active = centre_image.nonzero()
    if active.shape[0] == 0:
        return circles.view(height, width), owner.view(height, width)
    offsets = circle_offsets(radius).to(device)
    painted = (active[:, None, :] + offsets[None, :, :]).reshape(-1, 2)  # car by car, in E's row-major order
    car = torch.arange(active.shape[0], device=device).repeat_interleave(offsets.shape[0])
    values = centre_image[active[:, 0], active[:, 1]].repeat_interleave(offsets.shape[0])
    on_screen = inside(painted, height, width)
    cells = painted[on_screen, 0] * width + painted[on_screen, 1]
    car, values = car[on_screen], values[on_screen]
    # priority_rank sorts stably by value: among equal values the earlier car (lower index) ranks first.
    winners = first_by_rank(cells, priority_rank(values), height * width)
    circles[cells[winners]] = values[winners]
    owner[cells[winners]] = car[winners]
    return circles.view(height, width), owner.view(height, width)


def pixel_centre_points(pixels: torch.Tensor, depth: torch.Tensor, camera: Camera = APOLLO_CAMERA_5) -> torch.Tensor:
    """Back-project pixel centres ``(row + 0.5, col + 0.5)`` at ``depth``.

    Args:
        pixels: ``(K, 2)`` int64 ``(row, col)``.
        depth: ``(K,)`` metres, positive.

    Returns:
        ``(K, 3)`` points in metres, dtype of ``depth``; ``floor(P(q))`` is exactly the pixel.
    """
    return camera.backproject(pixels.to(depth.dtype) + 0.5, depth)


def shifted_target(points: torch.Tensor, shift: tuple[float, float], camera: Camera = APOLLO_CAMERA_5) -> torch.Tensor:
    """The target ``L``: occupancy of the points moved by ``(a, b, 0)``.

    Args:
        points: ``(K, 3)`` points ``Q`` in metres.
        shift: ``(a, b)`` in metres.

    Returns:
        ``(H, W)`` bool; points leaving the screen are dropped.
    """
    moved = points + shift_vector(shift, points)
    pixels, _ = screen_pixels(camera.project(moved), camera)
    return occupancy(pixels, camera.screen_shape)


def build_configuration(
    centres: torch.Tensor,
    shift: tuple[float, float] = SKY_SHIFT,
    camera: Camera = APOLLO_CAMERA_5,
    image_id: str = "",
    radius: float = CIRCLE_RADIUS,
) -> SkyConfiguration:
    """Build one Sky configuration from an image's car centres.

    Args:
        centres: ``(M, 3)`` car centres in metres, camera frame (``M`` may be 0).
        shift: the true shift ``(a, b)`` in metres: two finite numbers. A Sky configuration is the
            paper's 2-parameter construction, and nothing in it records the shift (a Sky file stores
            ``(a, b)``), so the depth shift ``(a, b, c)`` is refused here: build the set with ``(a, b)``
            and give it the depth targets of :func:`sdm.depth.depth_targets` (as Table 5 does).
        camera: camera and screen.
        image_id: name of the source image, kept for provenance.
        radius: the disc radius of a car in screen pixels (the paper's ``3 ln 4``).

    Returns:
        The configuration. An image with no car on screen gives an *empty*
        configuration (no points, empty target); trainers skip its gradient
        naturally (it contributes nothing) and metrics count it as 0 pixels.

    Raises:
        SDMInputError: naming ``shift`` unless it is two finite numbers; bad ``centres``.
    """
    size = shift.numel() if isinstance(shift, torch.Tensor) else len(shift) if isinstance(shift, (tuple, list)) else 0
    if size == 3:
        raise SDMInputError(
            f"shift must be (a, b): a Sky configuration is the paper's 2-parameter construction; for the depth "
            f"shift (a, b, c) build the set with (a, b) and use sdm.depth.depth_targets(set, (a, b, c)), got {shift!r}"
        )
    shift = check_shift(shift)
    centre_image = render_centres(centres, camera).to(torch.float64)
    circles, owner = paint_circles(centre_image, radius)
    pixels = circles.nonzero()
    depth = circles[pixels[:, 0], pixels[:, 1]]
    target = shifted_target(pixel_centre_points(pixels, depth, camera), shift, camera)
    centre_pixels = centre_image.nonzero()
    return SkyConfiguration(
        pixels=pixels,
        depth=depth,
        target=target,
        image_id=image_id,
        centres=centre_pixels,
        centre_depth=centre_image[centre_pixels[:, 0], centre_pixels[:, 1]],
        cars=owner[pixels[:, 0], pixels[:, 1]],
    )


#: How a car's disc follows the screen scale (:func:`rescaled_configuration`).
DISCS = ("pixels", "metres")


def scaled_camera(camera: Camera, scale: int) -> Camera:
    """``camera`` with a screen of ``scale`` times its rows and columns: the same image and intrinsics, so the
    screen pixels per image pixel (and per metre at any depth) grow ``scale`` times. Scale 1 is ``camera``."""
    if isinstance(scale, bool) or int(scale) != scale or scale < 1:
        raise SDMInputError(f"screen scale must be a positive integer, got {scale!r}")
    if scale == 1:
        return camera
    return Camera(fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy, image_width=camera.image_width,
                  image_height=camera.image_height, screen_height=camera.screen_height * int(scale),
                  screen_width=camera.screen_width * int(scale))


def disc_radius(scale: int, disc: str) -> float:
    """A car's disc radius in screen pixels on the screen scaled ``scale`` times: the paper's ``3 ln 4`` for
    ``disc = "pixels"``, ``scale`` times it for ``"metres"`` (the car's size in metres kept)."""
    if disc not in DISCS:
        raise SDMInputError(f"disc must be one of {', '.join(DISCS)}, got {disc!r}")
    return CIRCLE_RADIUS * (int(scale) if disc == "metres" else 1)


def rescaled_configuration(config: SkyConfiguration, camera: Camera, scale: int, disc: str = "pixels",
                           shift: tuple[float, float] = SKY_SHIFT) -> SkyConfiguration:
    """``config``'s cars rebuilt on the screen ``scaled_camera(camera, scale)``.

    Each car's centre is its pixel's centre on ``camera``'s screen, back-projected at its depth; the
    configuration is then built anew (:func:`build_configuration`, target at ``shift``). Scale 1 returns
    ``config`` itself.

    Args:
        disc: ``"pixels"``: a car's disc keeps its radius in screen pixels (the same points per car, covering
            ``1 / scale`` of the metres); ``"metres"``: the radius grows with the screen (the same size in metres,
            ``scale**2`` times the points).

    Raises:
        SDMInputError: naming ``disc`` unless it is one of :data:`DISCS`; naming the scale unless it is a
            positive integer.
    """
    radius = disc_radius(scale, disc)
    scaled = scaled_camera(camera, scale)
    if scaled is camera:
        return config
    centres = pixel_centre_points(config.centres, config.centre_depth, camera)
    return build_configuration(centres, shift, scaled, config.image_id, radius)


def add_target_noise(target: torch.Tensor, noise_level: int, generator: torch.Generator | None = None,
                     active: torch.Tensor | None = None, out: "NoiseBuffer | None" = None) -> torch.Tensor:
    """Move every active pixel of a target by independent integers uniform on ``[-level, level]``.

    Args:
        target: ``(..., H, W)`` bool target(s). The moves are drawn in the order of
            ``target.nonzero()`` (target by target, each row-major) as one
            ``randint`` call: from a CPU generator this is the same sequence as one
            call per target in turn (torch's CPU generator draws serially;
            ``test_sky.py`` holds it), so a stack of targets gets the same noise as a
            loop over them.
        level: noise level ``n >= 0`` in screen pixels.
        generator: source of randomness (seed it for reproducible runs).
        active: ``target.nonzero()`` where the caller has it already (many draws on one
            target); the search over every pixel is then skipped.
        out: a :class:`NoiseBuffer` of ``target``'s shape and device to draw into: the result is its
            ``targets`` (overwritten by the next draw into it), not a fresh tensor.

    Returns:
        ``(..., H, W)`` bool occupancy of the moved pixels (``out.targets`` where given); off-screen ones
        are dropped.
    """
    if int(noise_level) != noise_level or noise_level < 0:
        raise SDMInputError(f"noise level must be a non-negative integer, got {noise_level!r}")
    if out is not None and (out.targets.shape != target.shape or out.targets.device != target.device):
        raise SDMInputError(f"out must be a NoiseBuffer of shape {tuple(target.shape)} on {target.device}, "
                            f"got {tuple(out.targets.shape)} on {out.targets.device}")
    if noise_level == 0:
        return target.clone() if out is None else out.copy(target)
    if active is None:
        active = target.nonzero()  # (K, ndim): leading indices, then (row, col)
    # Drawn on the generator's device (CPU by default): the same seed gives the same moves wherever the target lives.
    draw_device = generator.device if generator is not None else target.device
    moves = torch.randint(-noise_level, noise_level + 1, (active.shape[0], 2), generator=generator, dtype=torch.int64,
                          device=draw_device)
    buffer = NoiseBuffer(target) if out is None else out
    return buffer.fill(active, moves.to(target.device))


class NoiseBuffer:
    """Memory for :func:`add_target_noise`'s draws, reused: many draws of the same shape into one buffer.

    A fresh 16 MB target stack per draw cost more in the first touch of its pages than the draw itself
    (512 targets of 128 x 256 in this project's VM), and zeroing it again as much; a buffer remembers
    which pixels its last draw set and clears only those.

    Attributes:
        targets: ``(..., H, W)`` bool, contiguous, on the device of ``like``: the last draw (zeros at first).
    """

    def __init__(self, like: torch.Tensor) -> None:
        self.targets = torch.zeros(like.shape, dtype=torch.bool, device=like.device)
        self._written = torch.zeros(0, dtype=torch.int64, device=like.device)  # flat indices of the set pixels
        self._count = 0  # how many of them (None: unknown, the whole buffer is zeroed before the next draw)

    def copy(self, target: torch.Tensor) -> torch.Tensor:
        """``target`` copied into :attr:`targets` (returned)."""
        self._count = None
        return self.targets.copy_(target)

    def fill(self, active: torch.Tensor, moves: torch.Tensor) -> torch.Tensor:
        """:attr:`targets` set to the pixels ``active`` (``(K, d)`` int64: leading indices, then ``(row, col)``)
        moved by ``moves`` (``(K, 2)`` int64), those off the grid dropped; returns it."""
        targets = self.targets
        height, width = targets.shape[-2:]
        if self._count is None:
            targets.zero_()
            self._count = 0
        if self._written.shape[0] < active.shape[0]:  # clear with the old list before it is replaced
            targets.view(-1).index_fill_(0, self._written[: self._count], False)
            self._written, self._count = torch.empty(active.shape[0], dtype=torch.int64, device=targets.device), 0
        if serves(targets, active, moves):  # one pass in C: clear the last draw, set this one's
            self._count = noise_fill(active=active.contiguous(), moves=moves.contiguous(), out=targets,
                                     written=self._written, n_written=self._count)
            return targets
        targets.view(-1).index_fill_(0, self._written[: self._count], False)
        moved = active[:, -2:] + moves
        kept = inside(moved, height, width)
        # Flat indices into it, filled in one call: 6.9 ms instead of 12 ms for an index per dimension
        # (512 targets of 128 x 256, one thread).
        lead_strides = torch.tensor(targets.stride()[:-2], dtype=torch.int64, device=targets.device)
        flat = ((active[:, :-2] * lead_strides).sum(1) + moved[:, 0] * width + moved[:, 1])[kept]  # no int matmul on CUDA
        targets.view(-1).index_fill_(0, flat, True)
        self._count = flat.shape[0]
        self._written[: self._count] = flat
        return targets


def noise_displacement(noise_level: int, mean_depth: float, camera: Camera = APOLLO_CAMERA_5) -> float:
    """Table 2's "Avg. Dist.": the expected 3D displacement, metres, that pixel noise ``noise_level`` stands for.

    ``mean_depth * E[sqrt((X * dx)^2 + (Y * dy)^2)]`` with ``X, Y`` independent
    uniform integers on ``[-level, level]`` and ``dx, dy`` the metres per
    screen column and row at unit depth (docs/method/paper.md, Experiments).
    """
    dy, dx = camera.metres_per_screen_pixel(1.0)
    steps = range(-noise_level, noise_level + 1)
    mean = sum(math.hypot(i * dx, j * dy) for i in steps for j in steps) / len(steps) ** 2
    return mean_depth * mean


def _check_centres(centres: torch.Tensor) -> torch.Tensor:
    if not isinstance(centres, torch.Tensor):
        centres = torch.as_tensor(centres, dtype=torch.float64)
    if centres.ndim != 2 or centres.shape[1] != 3:
        raise SDMInputError(f"car centres must have shape (M, 3), got {tuple(centres.shape)}")
    if not bool(torch.isfinite(centres).all()):
        raise SDMInputError("car centres must be finite")
    return centres.to(torch.float64)


def shift_vector(theta, like: torch.Tensor) -> torch.Tensor:
    """The shift ``theta = (a, b)`` as the 3-vector ``(a, b, 0)`` that moves points: the one conversion.

    A 3-element ``theta = (a, b, c)`` (the general shift with depth, :mod:`sdm.depth`) passes through.

    Args:
        theta: ``(..., 2)`` tensor (kept differentiable: its gradient is the flow on x and y)
            or two numbers ``(a, b)``, metres.
        like: tensor whose dtype and device the result takes (the points it will move).

    Returns:
        ``(..., 3)`` ``(a, b, 0)`` in metres, dtype and device of ``like``.
    """
    if isinstance(theta, torch.Tensor):
        if theta.shape[-1:] == (3,):  # the general shift (a, b, c) with depth (sdm.depth)
            return theta.to(dtype=like.dtype, device=like.device)
        if theta.shape[-1:] != (2,):
            raise SDMInputError(f"theta must have shape (..., 2) or (..., 3), got {tuple(theta.shape)}")
        return F.pad(theta.to(dtype=like.dtype, device=like.device), (0, 1))
    if isinstance(theta, (tuple, list)) and len(theta) == 3:  # (a, b, c): checked as (a, b) and c
        (a, b), (c, _) = check_shift(theta[:2]), check_shift((theta[2], 0.0))
        return torch.tensor([a, b, c], dtype=like.dtype, device=like.device)
    a, b = check_shift(theta)
    return torch.tensor([a, b, 0.0], dtype=like.dtype, device=like.device)


def check_shift(shift) -> tuple[float, float]:
    """``(a, b)`` as floats; :class:`SDMInputError` unless ``shift`` is two finite numbers."""
    try:
        a, b = (float(v) for v in shift)
    except (TypeError, ValueError):
        raise SDMInputError(f"shift must be two numbers (a, b), got {shift!r}") from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise SDMInputError(f"shift must be finite, got {shift!r}")
    return a, b

"""Pinhole camera and the 128 x 256 screen of the Sky dataset.

Coordinates
-----------
Camera frame, metres: x right, y down, z forward (ApolloCar3D convention).
Image, pixels: ``u`` is the column, ``v`` the row, of a ``image_width x
image_height`` image.
Screen, screen pixels: ``(row, col)`` floats on an ``H x W`` grid that covers
the *lower half* of the image::

    u = fx * x / z + cx            v = fy * y / z + cy
    row = v * 2H / image_height - H        col = u * W / image_width

so with the default 128 x 256 screen, ``row = v * 256/2710 - 128`` and
``col = u * 256/3384`` (docs/method/paper.md, Geometry). A point is in screen pixel
``(floor(row), floor(col))`` and on screen when ``0 <= row < H`` and
``0 <= col < W``. Pixels are not square.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import torch

from .errors import SDMInputError


@dataclass(frozen=True)
class Camera:
    """Intrinsics plus the screen they are rendered onto.

    Attributes:
        fx, fy: focal lengths in image pixels.
        cx, cy: principal point in image pixels.
        image_width, image_height: image size in pixels.
        screen_height, screen_width: screen size ``H x W`` in screen pixels; the
            screen covers the lower half of the image.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    image_width: int = 3384
    image_height: int = 2710
    screen_height: int = 128
    screen_width: int = 256

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise SDMInputError(f"Camera.{name} must be finite, got {value!r}")
        for name in ("fx", "fy", "image_width", "image_height", "screen_height", "screen_width"):
            if getattr(self, name) <= 0:
                raise SDMInputError(f"Camera.{name} must be positive, got {getattr(self, name)!r}")

    # -- scale factors --------------------------------------------------------
    @property
    def rows_per_image_pixel(self) -> float:
        """Screen rows per image pixel (0.0945 for ApolloCar3D)."""
        return 2 * self.screen_height / self.image_height

    @property
    def cols_per_image_pixel(self) -> float:
        """Screen columns per image pixel (0.0757 for ApolloCar3D)."""
        return self.screen_width / self.image_width

    @property
    def screen_shape(self) -> tuple[int, int]:
        return (self.screen_height, self.screen_width)

    # -- projection -------------------------------------------------------------
    def project(self, points: torch.Tensor, validate: bool = True) -> torch.Tensor:
        """Project camera-frame points onto the screen.

        Args:
            points: ``(..., 3)`` camera-frame coordinates in metres; every ``z``
                must be positive (in front of the camera).
            validate: check the points (skip only for points already checked).

        Returns:
            ``(..., 2)`` screen coordinates ``(row, col)`` in screen pixels,
            same dtype as ``points``; differentiable.

        Raises:
            SDMInputError: if ``points`` is not ``(..., 3)``, holds a non-finite
                value, or a point is on or behind the camera plane.
        """
        if validate:
            check_points(points, "points")
        x, y, z = points.unbind(-1)
        u = self.fx * x / z + self.cx
        v = self.fy * y / z + self.cy
        row = v * self.rows_per_image_pixel - self.screen_height
        col = u * self.cols_per_image_pixel
        return torch.stack((row, col), dim=-1)

    def backproject(self, screen: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        """Inverse of :meth:`project` at a given depth.

        Args:
            screen: ``(..., 2)`` screen coordinates ``(row, col)`` in screen pixels.
            depth: ``(...)`` depth ``z`` in metres, positive.

        Returns:
            ``(..., 3)`` camera-frame points in metres whose projection is ``screen``.
        """
        if screen.shape[-1:] != (2,):
            raise SDMInputError(f"screen must have shape (..., 2), got {tuple(screen.shape)}")
        if depth.shape != screen.shape[:-1]:
            raise SDMInputError(
                f"depth must have shape {tuple(screen.shape[:-1])} to match screen, got {tuple(depth.shape)}"
            )
        if bool((depth <= 0).any()) or not bool(torch.isfinite(depth).all()):
            raise SDMInputError("depth must be finite and positive (points in front of the camera)")
        row, col = screen.unbind(-1)
        u = col / self.cols_per_image_pixel
        v = (row + self.screen_height) / self.rows_per_image_pixel
        x = (u - self.cx) * depth / self.fx
        y = (v - self.cy) * depth / self.fy
        return torch.stack((x, y, depth), dim=-1)

    def metres_per_screen_pixel(self, depth: float | torch.Tensor) -> tuple:
        """Lateral size ``(dy, dx)`` in metres of one screen pixel (row, col) at ``depth``."""
        return (depth / (self.fy * self.rows_per_image_pixel), depth / (self.fx * self.cols_per_image_pixel))

    # -- construction -------------------------------------------------------------
    @classmethod
    def from_file(cls, path: str | Path, **screen) -> "Camera":
        """Read ApolloCar3D intrinsics (``fx = ...; fy = ...; cx = ...; cy = ...;``).

        The file is UTF-8 text (a byte-order mark is accepted). Extra keyword
        arguments (image and screen size) are passed to :class:`Camera`.

        Raises:
            SDMInputError: naming the file, if it is missing, unreadable or not
                UTF-8, lacks one of the four values, a value is not a finite
                number, a focal length is not positive, or the extra arguments
                are invalid.
        """
        path = Path(path)
        if not path.is_file():
            raise SDMInputError(f"{path}: camera intrinsics file not found")
        try:
            text = path.read_text(encoding="utf-8-sig")
        except UnicodeDecodeError as exc:
            raise SDMInputError(f"{path}: camera intrinsics file is not UTF-8 text ({exc})") from None
        except OSError as exc:
            raise SDMInputError(f"{path}: cannot read camera intrinsics file ({exc})") from None
        values = {}
        for key in ("fx", "fy", "cx", "cy"):
            match = re.search(rf"\b{key}\s*=\s*([^;\s]+)\s*;?", text)
            if match is None:
                raise SDMInputError(f"{path}: no '{key} = <number>;' line in camera intrinsics")
            try:
                values[key] = float(match.group(1))
            except ValueError:
                raise SDMInputError(f"{path}: {key} is not a number: {match.group(1)!r}") from None
            if not math.isfinite(values[key]):
                raise SDMInputError(f"{path}: {key} is not finite: {match.group(1)!r}")
            if key in ("fx", "fy") and values[key] <= 0:
                raise SDMInputError(f"{path}: {key} must be a positive focal length in pixels, got {match.group(1)!r}")
        try:
            return cls(**values, **screen)
        except SDMInputError as exc:
            raise SDMInputError(f"{path}: {exc}") from None


#: ``Camera_5`` of ApolloCar3D (and of the PKU/Baidu car-pose set), on the Sky screen.
APOLLO_CAMERA_5 = Camera(fx=2304.5479, fy=2305.8757, cx=1686.2379, cy=1354.9849)


def check_points(points: torch.Tensor, name: str = "points") -> None:
    """Raise :class:`SDMInputError` unless ``points`` is ``(..., 3)``, finite, with z > 0."""
    if not isinstance(points, torch.Tensor):
        raise SDMInputError(f"{name} must be a torch.Tensor, got {type(points).__name__}")
    if points.shape[-1:] != (3,):
        raise SDMInputError(f"{name} must have shape (..., 3), got {tuple(points.shape)}")
    if not points.is_floating_point():
        raise SDMInputError(f"{name} must be floating point, got {points.dtype}")
    finite = torch.isfinite(points.detach())
    if not bool(finite.all()):
        bad = int((~finite.all(-1)).sum())
        raise SDMInputError(f"{name}: {bad} point(s) have non-finite coordinates")
    behind = points.detach()[..., 2] <= 0
    if bool(behind.any()):
        raise SDMInputError(
            f"{name}: {int(behind.sum())} point(s) are on or behind the camera plane (z <= 0); "
            "drop them before projecting"
        )

"""Table 7's network: :class:`ShiftNet`, a small CNN from a configuration's images to its shift, and its weights
file (written atomically with the SHA-256 of its parameters, checked on reading)."""
from __future__ import annotations

import hashlib
import math
import pickle
from pathlib import Path

import torch
from torch import nn

from ...errors import SDMInputError
from ...io import write_atomic
from ...sky import SKY_SHIFT

class ShiftNet(nn.Module):
    """A small CNN: ``(B, 2, H, W)`` images -> ``(B, 2)`` shift ``(a, b)`` in metres (float64).

    Five convolutions of stride 2 (8, 16, 32, 32, 32 channels; the first 5 x 5, the others 3 x 3), each
    followed by a group normalisation (4 groups) and a ReLU, take a 128 x 256 screen to a 4 x 8 grid; the grid is
    flattened (positions matter: a shift moves the pixels) and two linear layers (``hidden`` units) give the
    shift in units of the prior: ``theta = centre + scale * head``, so that a fresh network starts near the
    prior's mean and every output moves on the scale of theta*'s spread. About 0.29 million parameters for a
    128 x 256 screen, most in the first linear layer; the narrow convolutions keep a step cheap on a CPU. Plain
    ``torch.nn``.

    Without the normalisation and the prior's units, some seeds' training runs kept the constant prediction for
    all their epochs (``docs/method/network.md``, "The network").

    Args:
        screen: ``(H, W)``, both divisible by 32.
        hidden: the hidden linear layer's width.
        centre: the prior's mean shift ``(a, b)``, metres (no label: theta*'s distribution, not its draws).
        scale: the prior's spread per axis, metres (> 0).
    """

    def __init__(self, screen: tuple[int, int] = (128, 256), hidden: int = 256,
                 centre: tuple[float, float] = SKY_SHIFT, scale: float = 0.15) -> None:
        super().__init__()
        height, width = screen
        if height % 32 or width % 32 or height < 32 or width < 32:
            raise SDMInputError(f"screen must have both sides divisible by 32, got {screen!r}")
        if not (math.isfinite(float(scale)) and float(scale) > 0):
            raise SDMInputError(f"scale must be a finite number > 0 (metres), got {scale!r}")
        widths = (2, 8, 16, 32, 32, 32)
        layers: list[nn.Module] = []
        for index, (fan_in, fan_out) in enumerate(zip(widths[:-1], widths[1:])):
            kernel = 5 if index == 0 else 3
            layers += [nn.Conv2d(fan_in, fan_out, kernel, stride=2, padding=kernel // 2), nn.GroupNorm(4, fan_out),
                       nn.ReLU()]
        self.screen = (int(height), int(width))
        self.features = nn.Sequential(*layers, nn.Flatten())
        self.head = nn.Sequential(nn.Linear(widths[-1] * (height // 32) * (width // 32), hidden), nn.ReLU(),
                                  nn.Linear(hidden, 2))
        self.register_buffer("centre", torch.tensor([float(v) for v in centre], dtype=torch.float64))
        self.register_buffer("scale", torch.tensor(float(scale), dtype=torch.float64))

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """``(B, 2, H, W)`` float32 -> ``(B, 2)`` float64 metres."""
        if images.ndim != 4 or images.shape[1] != 2 or tuple(images.shape[2:]) != self.screen:
            raise SDMInputError(f"images must have shape (B, 2, {self.screen[0]}, {self.screen[1]}), "
                                f"got {tuple(images.shape)}")
        return self.centre + self.scale * self.head(self.features(images)).double()


def parameter_count(net: nn.Module) -> int:
    """The number of trainable parameters."""
    return sum(p.numel() for p in net.parameters() if p.requires_grad)


def save_weights(net: ShiftNet, path: str | Path) -> Path:
    """Write ``net``'s state_dict to ``path`` atomically (a temporary file renamed), readable by others, with the
    SHA-256 of its parameters (:func:`weights_digest`) that :func:`load_weights` checks."""

    state = net.state_dict()
    saved = {"screen": list(net.screen), "state": state, "sha256": weights_digest(state)}
    return write_atomic(path, lambda temporary: torch.save(saved, temporary))


def weights_digest(state: dict) -> str:
    """The SHA-256 (hex) of a state_dict: every entry's name, dtype, shape and bytes, in the dict's order."""
    digest = hashlib.sha256()
    for name, tensor in state.items():
        tensor = tensor.detach().to("cpu").contiguous()
        digest.update(f"{name}|{tensor.dtype}|{tuple(tensor.shape)}|".encode())
        digest.update(tensor.view(-1).view(torch.uint8).numpy().tobytes() if tensor.numel() else b"")
    return digest.hexdigest()


def load_weights(path: str | Path, screen: tuple[int, int]) -> ShiftNet:
    """A :class:`ShiftNet` for ``screen`` with the weights :func:`save_weights` wrote to ``path`` (eval mode).

    Raises:
        SDMInputError: naming the file when it is not such a file, its parameters do not match their SHA-256 (a
            damaged file) or hold a value that is not finite, or it was saved for another screen.
    """
    rerun = "rerun its network_train stage"
    try:
        saved = torch.load(path, map_location="cpu", weights_only=True)
        state, stored = saved["state"], saved.get("sha256")
        if stored != weights_digest(state):
            raise SDMInputError(f"{path}: its weights do not match their SHA-256 (damaged, or written without one); "
                                f"{rerun}")
        bad = [name for name, tensor in state.items()
               if tensor.is_floating_point() and not bool(tensor.isfinite().all())]
        if bad:
            raise SDMInputError(f"{path}: weights {bad[:3]} hold values that are not finite; {rerun}")
        net = ShiftNet(tuple(saved["screen"]))
        net.load_state_dict(state)
    except SDMInputError:
        raise
    except (OSError, RuntimeError, KeyError, TypeError, ValueError, AttributeError, EOFError,
            pickle.UnpicklingError) as error:
        raise SDMInputError(f"{path}: not a ShiftNet weights file ({error}); {rerun}") from None
    if net.screen != tuple(screen):
        raise SDMInputError(f"{path}: weights for a {net.screen} screen, the data's is {tuple(screen)}")
    return net.eval()

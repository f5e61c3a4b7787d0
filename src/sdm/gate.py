"""The prior gate: a check after any method of Table 6 that returns to its start every unit whose estimate travelled
implausibly far under theta*'s prior (docs/method/objects.md, "The prior gate")."""
from __future__ import annotations

import torch

from . import sharing as S
from .errors import SDMInputError

#: The sharing levels whose rows have a prior spread here (as :data:`sdm.objects.SHARINGS`).
GATED_LEVELS = ("configuration", "car", "camera+car")


def prior_sd(sharing: S.Sharing, truth: S.TruthDistribution) -> torch.Tensor:
    """Each row's prior spread per axis (metres), as :func:`sdm.sharing.draw_truth` draws it: ``camera_sd`` for a
    configuration's or a camera's row, ``car_sd`` for a car's, ``residual_sd`` for a car's residual
    (``camera+car``).

    Returns:
        ``(K,)`` float64 on the CPU.
    """
    is_car = sharing.rows[:, 1].cpu() != S.NO_INDEX
    if sharing.level == "configuration":
        return torch.full((sharing.n_rows,), float(truth.camera_sd), dtype=torch.float64)
    if sharing.level == "car":
        return torch.full((sharing.n_rows,), float(truth.car_sd), dtype=torch.float64)
    if sharing.level == "camera+car":
        return torch.where(is_car, float(truth.residual_sd), float(truth.camera_sd)).to(torch.float64)
    raise SDMInputError(f"sharing level must be one of {', '.join(GATED_LEVELS)}, got {sharing.level!r}")


def prior_gate(theta: torch.Tensor, start: torch.Tensor, sd: torch.Tensor, gate: float
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """The prior gate: every row that ends farther than ``gate * sd`` from its start is returned to its start.

    A row's travel is the Euclidean norm of ``theta - start``. Under the prior a row's true shift lies farther than
    ``g`` standard deviations from its prior mean with probability ``exp(-g^2 / 2)`` (1.1 % at ``g = 3``), so a
    row that travels that far from a start near the mean has most likely been pulled onto pixels that are not its
    own (docs/method/objects.md, "The prior gate").

    Args:
        theta: ``(K, 2)`` metres, the rows' estimates.
        start: ``(K, 2)`` metres, the rows' starts (same device).
        sd: ``(K,)`` metres, each row's prior spread per axis (:func:`prior_sd`).
        gate: a positive number of standard deviations.

    Returns:
        ``(gated (K, 2) float64, returned (K,) bool)``, on ``theta``'s device: the gated rows and which were returned.
    """
    if isinstance(gate, bool) or not isinstance(gate, (int, float)) or not gate > 0:
        raise SDMInputError(f"gate must be a positive number of standard deviations, got {gate!r}")
    if theta.shape != start.shape or theta.dim() != 2 or theta.shape[1] != 2 or sd.shape != theta.shape[:1]:
        raise SDMInputError(f"theta and start must be (K, 2) and sd (K,), got {tuple(theta.shape)}, "
                            f"{tuple(start.shape)} and {tuple(sd.shape)}")
    theta, start = theta.to(torch.float64), start.to(theta.device, torch.float64)
    returned = (theta - start).norm(dim=1) > float(gate) * sd.to(theta.device, torch.float64)
    return torch.where(returned.unsqueeze(1), start, theta), returned

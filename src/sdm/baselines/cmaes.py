"""Gradient-free search on the exact pixel loss: CMA-ES (pycma) on the count of mismatched pixels.

The objective is what a researcher would write without any differentiable renderer: render the
shifted points at zoom 0 exactly as the target was made (``floor(P(Q + (a, b, 0)))``, occupancy,
off-screen points dropped; :func:`sdm.sky.shifted_target`) and count, summed over the training
configurations, the pixels where the rendering and the target disagree (false positives + false
negatives). It is a step function of ``theta``: no gradient, hence CMA-ES, whose ranking-based
update only needs to compare candidates.

The count for a whole training set is one vectorised pass: the on-screen pixels of all points as
flat ids ``config * H * W + row * W + col`` set a bitmap; ``|rendered| + |target| - 2 |overlap|``.

Budget: at most ``budget`` objective evaluations (pycma's ``maxfevals``; a generation is never cut,
so up to ``popsize - 1`` more), starting from ``theta0`` with step size ``sigma0`` metres. pycma also
stops on its own criteria (``tolx``, flat fitness); the result is the best candidate evaluated.

``cma`` is imported when a fit starts: it is a dependency of the workflow's baseline stage, not of
the ``sdm`` library. pycma seeds numpy's global generator with the run's seed (its ``seed`` option).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from ..batch import ConfigurationSet
from ..camera import Camera
from .common import FitResult, check_positive, check_positive_int, timed


@dataclass(frozen=True)
class CMAESSettings:
    """Hyper-parameters of the CMA-ES search.

    Attributes:
        sigma0: initial step size, metres (theta* is about 0.6 m from the start (0, 0)).
        budget: objective evaluations allowed.
        popsize: candidates per generation; 0 = pycma's default ``4 + floor(3 ln 2) = 6``.
        tolx: stop when the search distribution is narrower than this, metres.
    """

    sigma0: float = 0.3
    budget: int = 240
    popsize: int = 0
    tolx: float = 1e-5

    def __post_init__(self) -> None:
        check_positive(self, ("sigma0", "tolx"))
        check_positive_int(self, ("budget",))
        check_positive_int(self, ("popsize",), allow_zero=("popsize",))


class PixelMismatch:
    """The exact zoom-0 pixel loss of a training set, as a function of ``theta``.

    Args:
        train_set: configurations (points ``Q``, targets ``L``).
        camera: camera and screen; default the set's own.
    """

    def __init__(self, train_set: ConfigurationSet, camera: Camera | None = None) -> None:
        self.camera = camera or train_set.camera
        height, width = self.camera.screen_shape
        points = train_set.points  # (P, 3) float64 metres
        device = points.device
        # The projection is affine in theta for a fixed depth: row = row_0 + b fy' / z, col = col_0 + a fx' / z
        # (fy', fx': focal lengths in screen pixels). Precomputing row_0, col_0 and the two gains makes an
        # evaluation two multiply-adds per point instead of a projection; it agrees with
        # camera.project(Q + (a, b, 0)) to ~1e-13 pixel, so a floor can differ only for a point within
        # that distance of a pixel border.
        self.origin = self.camera.project(points)  # (P, 2) screen (row, col) at theta = 0
        self.gain = torch.stack((self.camera.fy * self.camera.rows_per_image_pixel / points[:, 2],
                                 self.camera.fx * self.camera.cols_per_image_pixel / points[:, 2]), dim=1)
        self.base = torch.repeat_interleave(torch.arange(len(train_set), device=device), train_set.counts) * (height * width)
        active = train_set.targets.nonzero()
        self.target_ids = active[:, 0] * (height * width) + active[:, 1] * width + active[:, 2]  # (K,) int64
        self.n_cells = len(train_set) * height * width
        self.evaluations = 0

    def __call__(self, theta) -> int:
        """False positives + false negatives at zoom 0, summed over the configurations (pixels)."""
        self.evaluations += 1
        height, width = self.camera.screen_shape
        shift = torch.tensor([float(theta[1]), float(theta[0])], dtype=self.origin.dtype, device=self.origin.device)
        pixels = torch.floor(torch.addcmul(self.origin, self.gain, shift)).to(torch.int64)  # (P, 2) row, col
        row, col = pixels.unbind(-1)
        keep = (row >= 0) & (row < height) & (col >= 0) & (col < width)
        ids = (self.base + row * width + col)[keep]
        rendered = torch.zeros(self.n_cells, dtype=torch.bool, device=self.origin.device)
        rendered[ids] = True
        # count_nonzero, not sum: summing a bool tensor this size first converts it to int64 (20x slower)
        n_rendered = int(rendered.count_nonzero())
        overlap = int(rendered[self.target_ids].count_nonzero())
        return n_rendered + int(self.target_ids.numel()) - 2 * overlap


def fit(train_set: ConfigurationSet, settings: CMAESSettings = CMAESSettings(), seed: int = 0,
        camera: Camera | None = None, theta0=(0.0, 0.0)) -> FitResult:
    """Minimise :class:`PixelMismatch` with CMA-ES.

    Args:
        seed: seeds pycma (``seed + 1``: pycma treats 0 as "seed from the clock").

    Returns:
        :class:`~sdm.baselines.common.FitResult`; history has one row per generation (``stage`` =
        generation, ``loss`` = its best count, ``a, b`` = the best candidate so far).
    """
    import cma

    def run() -> FitResult:
        objective = PixelMismatch(train_set, camera)
        options = {
            "seed": int(seed) % (2**31 - 2) + 1,
            "maxfevals": int(settings.budget),
            "tolx": float(settings.tolx),
            "tolfun": 0.0,
            "tolfunhist": 0.0,
            "verbose": -9,
            "verb_disp": 0,
            "verb_log": 0,
        }
        if settings.popsize:
            options["popsize"] = int(settings.popsize)
        strategy = cma.CMAEvolutionStrategy([float(v) for v in theta0], float(settings.sigma0), options)
        history = {"stage": [], "loss": [], "a": [], "b": []}
        best_value, best_theta = objective(theta0), tuple(float(v) for v in theta0)
        generation = 0
        while not strategy.stop():
            candidates = strategy.ask()
            values = [objective(x) for x in candidates]
            strategy.tell(candidates, values)
            winner = min(range(len(values)), key=values.__getitem__)
            if values[winner] < best_value:
                best_value, best_theta = values[winner], (float(candidates[winner][0]), float(candidates[winner][1]))
            history["stage"].append(generation)
            history["loss"].append(float(min(values)))
            history["a"].append(best_theta[0])
            history["b"].append(best_theta[1])
            generation += 1
        return FitResult(best_theta, 0.0, objective.evaluations, history)

    return timed(run)

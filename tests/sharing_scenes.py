"""Sets with a car index per point, for the tests of per-row shifts (independent of the Sky file format).

A point belongs to the car whose disc gave it its depth (the ``rmin`` winner of ``E'``): among the
configuration's car centres on screen within the circle radius of the point's pixel, the nearest in
depth (the first such centre in row-major order on a tie of depths).
"""
from __future__ import annotations

import math

import torch

from sdm.batch import ConfigurationSet
from sdm.sky import CIRCLE_RADIUS, SKY_SHIFT, build_configuration

from scenes import configurations


def cars_of(configuration) -> torch.Tensor:
    """``(p,)`` int64 the car (index into ``configuration.centres``) of each point."""
    if configuration.num_points == 0:
        return torch.zeros(0, dtype=torch.int64)
    delta = (configuration.pixels[:, None, :] - configuration.centres[None, :, :]).double()
    within = delta.pow(2).sum(-1) <= CIRCLE_RADIUS**2  # (p, M)
    depth = torch.where(within, configuration.centre_depth[None, :], torch.full_like(delta[..., 0], math.inf))
    cars = depth.argmin(1)
    assert torch.equal(depth.gather(1, cars[:, None])[:, 0], configuration.depth)
    return cars


def set_with_cars(configs) -> tuple[ConfigurationSet, torch.Tensor, torch.Tensor]:
    """``(set, cars (P,), n_cars (N,))`` of built configurations."""
    data = ConfigurationSet.from_configurations(configs)
    cars = torch.cat([cars_of(c) for c in configs]) if configs else torch.zeros(0, dtype=torch.int64)
    n_cars = torch.tensor([c.centres.shape[0] for c in configs], dtype=torch.int64)
    return data, cars, n_cars


def road_set(n: int, seed: int = 0, mean_cars: int = 11):
    """``set_with_cars`` of ``n`` seeded road scenes (tests/scenes.py)."""
    return set_with_cars(configurations(n, seed, SKY_SHIFT, mean_cars))


def car_row_scene(n_cars: int, n_configs: int = 1, seed: int = 0):
    """``n_configs`` images of ``n_cars`` cars side by side at 12-40 m, discs apart (one row per car each)."""
    generator = torch.Generator().manual_seed(seed)
    configs = []
    for i in range(n_configs):
        z = 12.0 + 28.0 * torch.rand(n_cars, generator=generator, dtype=torch.float64)
        x = torch.linspace(-0.35, 0.35, n_cars, dtype=torch.float64) * z if n_cars > 1 else torch.zeros(1)
        x = x.double() + 0.05 * z * (torch.rand(n_cars, generator=generator, dtype=torch.float64) - 0.5)
        y = 1.4 + 0.07 * z
        configs.append(build_configuration(torch.stack((x, y, z), 1), SKY_SHIFT, image_id=f"row{i}"))
    return set_with_cars(configs)

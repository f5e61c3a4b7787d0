"""Sets with a car index per point, for the tests of per-row shifts (independent of the Sky file format).

A point belongs to the car whose disc gave it its depth (the ``rmin`` winner of ``E'``): among the
configuration's car centres on screen within the circle radius of the point's pixel, the nearest in
depth (the first such centre in row-major order on a tie of depths).
"""
from __future__ import annotations

import math

import torch

from sdm.batch import ConfigurationSet
from sdm.camera import APOLLO_CAMERA_5
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


def car_grid_scene(n_cars: int, n_configs: int = 1, seed: int = 0, near: float = 12.0, far: float = 60.0):
    """``n_configs`` images of ``n_cars`` cars each, centres on distinct nodes of a screen grid (16 columns
    apart, 18 rows apart: discs 9 pixels wide never touch), depths uniform on ``[near, far]`` metres."""
    camera = APOLLO_CAMERA_5
    nodes = torch.tensor([[row, col] for row in range(20, 128 - 8, 18) for col in range(8, 256 - 4, 16)],
                         dtype=torch.float64)
    if n_cars > nodes.shape[0]:
        raise ValueError(f"at most {nodes.shape[0]} cars fit the grid, got {n_cars}")
    generator = torch.Generator().manual_seed(seed)
    configs = []
    for i in range(n_configs):
        chosen = nodes[torch.randperm(nodes.shape[0], generator=generator)[:n_cars]]
        depth = near + (far - near) * torch.rand(n_cars, generator=generator, dtype=torch.float64)
        centres = camera.backproject(chosen + 0.5, depth)
        configs.append(build_configuration(centres, SKY_SHIFT, camera, image_id=f"grid{n_cars}-{i}"))
    return set_with_cars(configs)

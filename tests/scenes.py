"""Small, seeded road scenes for the core tests (independent of the data layer)."""
from __future__ import annotations

import torch

from sdm.batch import ConfigurationSet
from sdm.sky import SKY_SHIFT, build_configuration


def road_centres(generator: torch.Generator, n_cars: int) -> torch.Tensor:
    """``(n_cars, 3)`` car centres on a road plane seen from a roof camera (y grows with z)."""
    z = 6.0 + 100.0 * torch.rand(n_cars, generator=generator, dtype=torch.float64) ** 1.3
    x = (torch.rand(n_cars, generator=generator, dtype=torch.float64) - 0.5) * (6.0 + 0.5 * z)
    y = 1.4 + 0.07 * z + 0.2 * torch.rand(n_cars, generator=generator, dtype=torch.float64)
    return torch.stack((x, y, z), dim=1)


def configurations(n: int, seed: int = 0, shift=SKY_SHIFT, mean_cars: int = 11):
    generator = torch.Generator().manual_seed(seed)
    out = []
    for i in range(n):
        n_cars = int(torch.randint(max(1, mean_cars - 6), mean_cars + 7, (1,), generator=generator))
        out.append(build_configuration(road_centres(generator, n_cars), shift, image_id=f"scene{i:05d}"))
    return out


def configuration_set(n: int, seed: int = 0, shift=SKY_SHIFT) -> ConfigurationSet:
    return ConfigurationSet.from_configurations(configurations(n, seed, shift))

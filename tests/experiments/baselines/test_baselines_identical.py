"""Speed-ups of the gradient baselines that must not change a bit: each against the
formulation it replaced, values and gradients compared with ``torch.equal``."""
import math

import pytest
import torch

from sdm.experiments.baselines import chamfer, silhouette


def window_splat(screen, config, n_configs, noise_level, sigma, shape):
    """The soft silhouette as it was written before: every window cell's row and column as ``(P, n, 2)``."""
    block = 1 << noise_level
    height, width = shape[0] // block, shape[1] // block
    position = screen / block
    nearest = torch.floor(position.detach()).to(torch.int64)
    reach = max(1, math.ceil(3.0 * sigma))
    steps = torch.arange(-reach, reach + 1)
    cells = nearest.unsqueeze(1) + torch.cartesian_prod(steps, steps)  # (P, n, 2)
    keep = (cells[..., 0] >= 0) & (cells[..., 0] < height) & (cells[..., 1] >= 0) & (cells[..., 1] < width)
    row = cells[..., 0].clamp(0, height - 1)
    col = cells[..., 1].clamp(0, width - 1)
    flat = (config.unsqueeze(1) * height + row) * width + col
    delta = cells.to(screen.dtype) + 0.5 - position.unsqueeze(1)
    weight = torch.exp((delta * delta).sum(-1) * (-0.5 / (sigma * sigma))) * keep
    log_empty = torch.log1p(-weight.clamp(max=1.0 - 1e-6))
    total = torch.zeros(n_configs * height * width, dtype=screen.dtype)
    total = total.index_add(0, flat.reshape(-1), log_empty.reshape(-1))
    return (-torch.expm1(total)).view(n_configs, height, width)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("zoom,sigma", [(0, 0.5), (2, 1.0), (3, 0.3)])
def test_soft_silhouette_is_the_window_formulation_to_the_bit(dtype, zoom, sigma):
    """Points all over a 64 x 96 screen and beyond its edges (clamped windows), three configurations."""
    generator = torch.Generator().manual_seed(zoom)
    screen = (torch.rand(300, 2, generator=generator, dtype=torch.float64) * torch.tensor([80.0, 120.0]) - 8.0)
    screen = screen.to(dtype).requires_grad_(True)
    config = torch.randint(0, 3, (300,), generator=generator)
    weights = torch.rand(3, 64 >> zoom, 96 >> zoom, generator=generator, dtype=dtype)
    ours = silhouette.soft_silhouette(screen, config, 3, zoom, sigma, (64, 96))
    (grad_ours,) = torch.autograd.grad((ours * weights).sum(), screen)
    theirs = window_splat(screen, config, 3, zoom, sigma, (64, 96))
    (grad_theirs,) = torch.autograd.grad((theirs * weights).sum(), screen)
    assert torch.equal(ours, theirs) and torch.equal(grad_ours, grad_theirs)
    assert 0 < float(ours.detach().max()) < 1


def test_chamfer_nearest_neighbours_are_argmin_to_the_bit():
    """Whole-pixel positions: many tied distances, where only the first index of the minimum is right."""
    generator = torch.Generator().manual_seed(5)
    points = torch.randint(0, 12, (6, 40, 2), generator=generator).to(torch.float64).requires_grad_(True)
    centres = torch.randint(0, 12, (6, 30, 2), generator=generator).to(torch.float64) + 0.5
    point_mask = torch.rand(6, 40, generator=generator) > 0.2
    centre_mask = torch.rand(6, 30, generator=generator) > 0.2
    ours = chamfer.chamfer_2d(points, point_mask, centres, centre_mask)
    (grad_ours,) = torch.autograd.grad(ours.sum(), points)
    search_points = torch.where(point_mask.unsqueeze(-1), points.detach(), -chamfer.FAR).float()
    search_centres = torch.where(centre_mask.unsqueeze(-1), centres, chamfer.FAR).float()
    squared = torch.cdist(search_points, search_centres)
    nearest_centre, nearest_point = squared.argmin(dim=2), squared.argmin(dim=1)
    to_target = ((points - centres.gather(1, nearest_centre.unsqueeze(-1).expand(-1, -1, 2))) ** 2).sum(-1)
    to_points = ((points.gather(1, nearest_point.unsqueeze(-1).expand(-1, -1, 2)) - centres) ** 2).sum(-1)
    theirs = (torch.where(point_mask, to_target, torch.zeros_like(to_target)).sum(1) / point_mask.sum(1)
              + torch.where(centre_mask, to_points, torch.zeros_like(to_points)).sum(1) / centre_mask.sum(1))
    (grad_theirs,) = torch.autograd.grad(theirs.sum(), points)
    assert torch.equal(ours, theirs) and torch.equal(grad_ours, grad_theirs)
    ties = (squared == squared.min(dim=2, keepdim=True).values).sum(2)
    assert int((ties > 1).sum()) > 10  # the ties are there to be broken

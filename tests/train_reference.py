"""The single-run SGD loop that ``sdm.train.train`` ran before one engine trained every run: the reference.

``sdm.train.train_runs`` (torch path and compiled engine alike) must give each run this loop's theta
history to the bit (``test_train.py``, ``test_native.py``); with ``fit_depth`` to 1e-12 m
(``test_depth.py``). Kept as it was: one layer call per mini-batch, autograd, ``theta -= rate * grad``.
"""
from __future__ import annotations

import functools

import torch

from sdm.batch import ConfigurationSet, PointBatch
from sdm.mapping import SpatialDomainMapping
from sdm.mapping.crossing import CROSSING_FINEST_COARSE, group_crossing_flow
from sdm.mapping.flow import dynamic_flow
from sdm.mapping.rules import by_zoom
from sdm.sky import shift_vector
from sdm.train import TrainSettings


def reference_train(train_set: ConfigurationSet, settings: TrainSettings, camera=None, method: str = "fast",
                    theta0=(0.0, 0.0), param_index=None, row_rate=None, zooms=None, rates=None,
                    crossing_widths=None, row_zoom=None) -> tuple[torch.Tensor, torch.Tensor]:
    """``(theta (steps + 1, n_params), loss (steps,))`` float64 CPU of one run (the set's own targets).

    ``param_index`` ``(P, G)`` (parameters attached to points): ``theta0`` is ``(K, 2)``, each point moved by the sum
    of its rows in column order, and theta comes back ``(steps + 1, K, 2)``, every step. ``row_zoom`` ``(K,)``:
    each row's first zoom; above it the row's step is skipped.

    ``zooms``: the loss zooms trained one after another (default ``s .. zoom``; a refinement's ``0, 0, ...``);
    ``rates``: the learning rate of each (default ``lr``, times ``lr_decay`` after each zoom); ``crossing_widths``:
    per entry of ``zooms``, ``group_crossing``'s kernel half-width there (metres; ``settings.rule`` must be
    ``"group_crossing"``): a refinement's passes'.
    """
    camera = camera or train_set.camera
    device = train_set.device
    zooms = list(range(settings.s, settings.zoom - 1, -1)) if zooms is None else list(zooms)
    if crossing_widths is None:
        rules = [settings.rule] * len(zooms)
    else:
        assert settings.rule == "group_crossing" and len(crossing_widths) == len(zooms)
        rules = [by_zoom(functools.partial(group_crossing_flow, width=width), dynamic_flow, CROSSING_FINEST_COARSE)
                 for width in crossing_widths]
    layers = [SpatialDomainMapping(camera, s=settings.s, zoom=zoom, method=method, rule=rule,
                                   fit_depth=settings.fit_depth) for zoom, rule in zip(zooms, rules)]
    n_configs = len(train_set)
    start = torch.as_tensor(theta0, dtype=torch.float64, device=device)
    if settings.fit_depth and start.shape == (2,):
        start = torch.nn.functional.pad(start, (0, 1))
    theta = start.clone().requires_grad_(True)
    rows = None if param_index is None else torch.as_tensor(param_index).reshape(train_set.points.shape[0], -1)
    generator = torch.Generator(device="cpu").manual_seed(settings.seed)
    pyramid = train_set.pyramid(settings.s)
    batch_size = settings.batch_size
    batches_per_epoch = n_configs // batch_size
    total = len(zooms) * settings.n_epoch * batches_per_epoch
    thetas = torch.empty(total + 1, *start.shape, dtype=torch.float64, device=device)
    thetas[0] = theta.detach()
    losses = torch.zeros(total, dtype=torch.float64, device=device)
    if rates is None:  # lr, then lr_decay times the last, one product at a time
        rates = [settings.lr]
        while len(rates) < len(zooms):
            rates.append(rates[-1] * settings.lr_decay)
    step = 0
    for zoom, layer, rate in zip(zooms, layers, rates):
        rate_scale = settings.rate_scale(zoom, start) if settings.fit_depth else None
        for _ in range(settings.n_epoch):
            order = torch.randperm(n_configs, generator=generator, device="cpu").to(device)
            epoch = _EpochLayout(train_set, order, batch_size, rows)
            for index in range(batches_per_epoch):
                batch, configs = epoch.batch(index)
                if batch.points.shape[0]:
                    if rows is None:
                        moves = shift_vector(theta, batch.points)
                    else:  # each point by the sum of its rows, one row at a time
                        point_rows = epoch.rows_of(index)
                        shift = theta[point_rows[:, 0]]
                        for column in range(1, point_rows.shape[1]):
                            shift = shift + theta[point_rows[:, column]]
                        moves = shift_vector(shift, batch.points)
                    out = layer(
                        batch.points + moves, batch.pixels,
                        pyramid[zoom].index_select(0, configs), batch.config, batch.rank, target_is_zoomed=True,
                        validate=False,
                    )
                    out.loss.backward()
                    with torch.no_grad():
                        if row_zoom is not None:  # the rows whose first zoom is below this one stay
                            rate_k = rate * (row_rate if row_rate is not None else torch.ones(len(row_zoom)))
                            move = rate_k[:, None] * theta.grad
                            move[torch.as_tensor(row_zoom) < zoom] = 0.0
                            theta -= move
                        elif row_rate is not None:
                            theta -= (rate * row_rate)[:, None] * theta.grad
                        else:
                            theta -= rate * theta.grad if not settings.fit_depth else rate * rate_scale * theta.grad
                    theta.grad = None
                    losses[step] = out.loss.detach()
                thetas[step + 1] = theta.detach()
                step += 1
    return thetas.cpu(), losses.cpu()


class _EpochLayout:
    """One epoch's shuffled configurations, their points laid out batch after batch."""

    def __init__(self, data: ConfigurationSet, order: torch.Tensor, batch_size: int, param_rows=None) -> None:
        self.batch_size = batch_size
        self.configs = order[: (len(order) // batch_size) * batch_size]
        rows, _ = data.rows(self.configs)
        self.points = data.points.index_select(0, rows)
        self.pixels = data.pixels.index_select(0, rows)
        self.rank = data.rank.index_select(0, rows)
        self.param_rows = None if param_rows is None else param_rows.index_select(0, rows)
        counts = data.counts.index_select(0, self.configs)
        self.local = torch.repeat_interleave(torch.arange(len(self.configs), device=order.device) % batch_size, counts)
        self.bounds = [0] + counts.view(-1, batch_size).sum(1).cumsum(0).tolist()

    def batch(self, index: int) -> tuple[PointBatch, torch.Tensor]:
        lo, hi = self.bounds[index], self.bounds[index + 1]
        configs = self.configs[index * self.batch_size : (index + 1) * self.batch_size]
        rows = slice(lo, hi)
        return PointBatch(self.points[rows], self.pixels[rows], self.local[rows], self.rank[rows], None), configs

    def rows_of(self, index: int) -> torch.Tensor:
        return self.param_rows[self.bounds[index] : self.bounds[index + 1]]

"""The torch path of the training engine (:func:`sdm.train.train_runs`): every device, every rule, ``fit_depth`` and
the dense grid; one layer call per SGD step, the ``R`` runs' mini-batches packed into it, autograd summing each run's
flow (docs/library.md).
"""
from __future__ import annotations

import torch

from ..batch import ConfigurationSet, PointBatch
from ..errors import SDMInputError
from ..mapping import SpatialDomainMapping
from ..mapping.rules import crossing_width_rule
from ..sharing import point_shifts
from ..sky import shift_vector


def train_torch(train_set, pyramids, settings, camera, method, zooms, rates, orders, starts, bar, rows=None,
                 record_every=1, row_rate=None, widths=None):
    """The torch path of :func:`train_runs`: ``(thetas (steps / record_every + 1, R, ...), losses (steps, R))`` on
    the set's device."""
    common, n_runs = settings[0], len(settings)
    device, batch_size = train_set.device, common.batch_size
    # Run r's target of configuration c is row r * N + c of each zoom.
    pyramid = pyramids[0] if n_runs == 1 else [torch.cat(at_zoom) for at_zoom in zip(*pyramids)]
    # Per entry of zooms: its rule (group_crossing's kernel width may differ pass by pass) and its layer.
    # With several runs the rule is applied run by run (the chain stays one call), so each run's loss is its own.
    built, layers, runners = {}, [], []
    for index, zoom in enumerate(zooms):
        width = None if widths is None else widths[index]
        if (zoom, width) not in built:
            rule = crossing_width_rule(common.rule, width)
            runner = rule if n_runs == 1 else RunByRun(rule, n_runs, batch_size)
            built[zoom, width] = (SpatialDomainMapping(camera, s=common.s, zoom=zoom, method=method, rule=runner,
                                                       fit_depth=common.fit_depth), runner)
        layers.append(built[zoom, width][0])
        runners.append(built[zoom, width][1])
    theta = starts.clone().requires_grad_(True)
    total = len(zooms) * common.n_epoch * (len(train_set) // batch_size)
    thetas = torch.empty(total // record_every + 1, *theta.shape, dtype=torch.float64, device=device)
    thetas[0] = theta.detach()
    losses = torch.zeros(total, n_runs, dtype=torch.float64, device=device)
    step = 0
    for entry, (zoom, rate) in enumerate(zip(zooms, rates)):
        # Per-parameter learning-rate factors: c learns at its own rate (depth_lr_scale) down to depth_zoom.
        rate_scale = common.rate_scale(zoom, theta) if common.fit_depth else None
        for epoch_index in range(common.n_epoch):
            epoch = RunsEpochLayout(train_set, orders[entry * common.n_epoch + epoch_index].to(device),
                                     batch_size, rows)
            for index in range(epoch.steps):
                batch, target_rows, run_of_point, run_bounds = epoch.batch(index)
                if batch.points.shape[0]:  # a step where every run drew empty configurations pulls nothing
                    if rows is not None:  # each point moved by the sum of its rows of its run's theta
                        moves = shift_vector(point_shifts(theta, epoch.rows_of(index), run_of_point), batch.points)
                    # One run: theta broadcast, so that autograd sums the flow as the single-run loop did.
                    elif n_runs == 1:
                        moves = shift_vector(theta[0], batch.points)
                    else:
                        moves = shift_vector(theta, batch.points).index_select(0, run_of_point)  # (P, 3)
                    rule = runners[entry]
                    if n_runs > 1:
                        rule.bounds = run_bounds
                    out = layers[entry](
                        batch.points + moves, batch.pixels, pyramid[zoom].index_select(0, target_rows),
                        batch.config, batch.rank, target_is_zoomed=True, validate=False,
                    )
                    out.loss.backward()
                    with torch.no_grad():  # plain SGD, per run: theta_r <- theta_r - lr * grad_r
                        if row_rate is not None:  # each row at its own rate (as the kernel rounds it)
                            theta -= (rate * row_rate[entry])[:, None] * theta.grad
                        elif common.fit_depth:
                            theta -= rate * rate_scale * theta.grad
                        else:
                            theta -= rate * theta.grad
                    theta.grad = None
                    losses[step] = out.loss.detach() if n_runs == 1 else rule.losses
                    finite = torch.isfinite(theta).reshape(n_runs, -1).all(1)
                    if not bool(finite.all()):
                        run = int((~finite).nonzero()[0])
                        raise SDMInputError(f"theta of run {run} became non-finite at step {step + 1} "
                                            f"(lr {rate!r} too large?)")
                step += 1
                if step % record_every == 0:
                    thetas[step // record_every] = theta.detach()
                bar.update()
    return thetas, losses


class RunByRun:
    """A gradient rule applied to each run's points of a packed step on their own: per-run losses.

    The rule sees exactly what a single run's step would give it (its configurations numbered
    ``0..B-1``, its ``B`` targets), so flow and loss are that run's to the bit. Set ``bounds``
    (``R + 1`` point offsets of the runs in the step) before each call; ``losses`` ``(R,)``
    holds the runs' losses after it.
    """

    def __init__(self, rule, n_runs: int, batch_size: int) -> None:
        self.rule, self.n_runs, self.batch_size = rule, n_runs, batch_size
        self.bounds: list[int] = []
        self.losses: torch.Tensor | None = None

    def __call__(self, screen, depth, config, landed, block, landing, target, zoom, camera):
        flows, losses, matched = [], [], []
        for run in range(self.n_runs):
            lo, hi = self.bounds[run], self.bounds[run + 1]
            if hi == lo:  # this run drew only empty configurations: it is not pulled
                losses.append(screen.new_zeros(()))
                continue
            first = run * self.batch_size
            flow, loss, hit = self.rule(screen[lo:hi], depth[lo:hi], config[lo:hi] - first, landed[lo:hi],
                                        block[lo:hi], landing[lo:hi], target[first : first + self.batch_size], zoom,
                                        camera)
            flows.append(flow), losses.append(loss), matched.append(hit)
        self.losses = torch.stack(losses).detach()
        return torch.cat(flows), self.losses.sum(), torch.cat(matched)


class RunsEpochLayout:
    """One epoch of ``R`` runs: step ``i`` is the concatenation of every run's mini-batch ``i``.

    Points are gathered once per epoch in (step, run, configuration) order, so
    each step is a contiguous slice, and so is each run's part of it. In a step,
    configuration ``j`` of run ``r`` is batch configuration ``r * batch_size + j``.
    """

    def __init__(self, data: ConfigurationSet, orders: torch.Tensor, batch_size: int,
                 param_rows: torch.Tensor | None = None) -> None:
        n_runs, n_configs = orders.shape
        self.batch_size, self.n_runs = batch_size, n_runs
        self.steps = steps = n_configs // batch_size
        kept = orders[:, : steps * batch_size].reshape(n_runs, steps, batch_size)
        self.configs = kept.transpose(0, 1).reshape(-1)  # (steps * R * B,) step-major
        runs = torch.arange(n_runs, device=orders.device)[None, :, None].expand(steps, n_runs, batch_size).reshape(-1)
        self.target_rows = runs * n_configs + self.configs
        rows, position = data.rows(self.configs)  # position: each row's index into self.configs
        self.points = data.points.index_select(0, rows)
        self.pixels = data.pixels.index_select(0, rows)
        self.rank = data.rank.index_select(0, rows)
        self.param_rows = None if param_rows is None else param_rows.index_select(0, rows)  # (P_epoch, G)
        per_run = data.counts.index_select(0, self.configs).view(steps, n_runs, batch_size).sum(2)  # (steps, R)
        self.local = position % (n_runs * batch_size)
        self.run = torch.div(self.local, batch_size, rounding_mode="floor")
        self.bounds = [0] + per_run.sum(1).cumsum(0).tolist()
        self.run_bounds = torch.nn.functional.pad(per_run.cumsum(1), (1, 0)).tolist()  # (steps, R + 1) in a step

    def batch(self, index: int) -> tuple[PointBatch, torch.Tensor, torch.Tensor, list[int]]:
        """Step ``index``: its points, the target row of each of its ``R * B`` configurations, the run of each
        point, and the ``R + 1`` offsets of the runs' points in the step."""
        lo, hi = self.bounds[index], self.bounds[index + 1]
        group = self.n_runs * self.batch_size
        target_rows = self.target_rows[index * group : (index + 1) * group]
        rows = slice(lo, hi)
        batch = PointBatch(self.points[rows], self.pixels[rows], self.local[rows], self.rank[rows], None)
        return batch, target_rows, self.run[rows], self.run_bounds[index]

    def rows_of(self, index: int) -> torch.Tensor:
        """``(P_step, G)`` int64: the param_index rows of step ``index``'s points."""
        return self.param_rows[self.bounds[index] : self.bounds[index + 1]]

"""The refinement passes after the paper's coarse-to-fine training: :func:`refine_runs` continues a :class:`RunsHistory` with a
:class:`Refinement` (docs/method/floor.md, "The schedule that reaches the floor").
"""
from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import torch
from tqdm.std import tqdm

from ..batch import ConfigurationSet
from ..camera import Camera
from ..errors import SDMInputError
from .checks import check_divergence, checked_runs
from .engine import shufflings, train_steps
from .settings import Refinement, RunsHistory, TrainSettings, refine_seed


def refine_runs(train_set: ConfigurationSet, targets: Sequence[torch.Tensor], settings: Sequence[TrainSettings],
                history: RunsHistory, refinement: Refinement, camera: Camera | None = None,
                device: torch.device | str | None = None, param_index: torch.Tensor | None = None,
                row_rate: torch.Tensor | None = None) -> RunsHistory:
    """``history`` (of :func:`train_runs` with these arguments) continued by ``refinement``'s passes.

    The passes train at zoom ``zoom`` only, through the whole chain ``s .. zoom`` (the forward of the
    schedule's last zoom), from each run's last theta, on the paths of :func:`train_runs` (compiled where
    it applies: for ``group_crossing`` on float64 CPU points; else packed runs in torch). Their steps are
    epochs of the training set (shuffled mini-batches, the incomplete last one dropped): run ``r`` draws one
    permutation per epoch from a generator seeded :func:`refine_seed` ``(settings[r].seed)``. A pass is the
    fewest whole epochs that hold its ``pass_steps`` steps, cut after them, at its own rate and
    ``group_crossing`` kernel half-width (:meth:`Refinement.rates`, :attr:`Refinement.widths`): where an epoch's
    steps divide ``pass_steps`` (the default's 32 steps an epoch; 2 of a 41-configuration set) no step is cut
    and every pass is one program; elsewhere each pass is its own program and the steps of its last epoch beyond ``pass_steps``
    are computed and dropped (a set of more than ``16 * pass_steps`` configurations computes a whole epoch
    per pass). Returns the whole history: the steps of ``history``, then the refinement's
    :attr:`Refinement.steps`. ``param_index``: that of :func:`train_runs` (the passes move the same rows, with
    ``row_rate``; their theta is recorded after every step).
    """
    if not isinstance(history, RunsHistory):
        raise SDMInputError(f"history must be the RunsHistory of train_runs, got {type(history).__name__}")
    trained_rows = history.theta.dim() == 4  # (steps + 1, R, K, 2): trained with param_index
    if trained_rows != (param_index is not None):
        raise SDMInputError(
            "param_index: the history was trained with parameters attached to points "
            f"({history.theta.shape[2]} rows a run); pass its param_index" if trained_rows else
            "param_index: the history was trained with one shift a run (no param_index); refine it without one")
    if history.theta.dim() < 3 or history.theta.shape[1] != len(settings):
        raise SDMInputError(f"history holds {history.theta.shape[1] if history.theta.dim() > 1 else 0} runs, "
                            f"settings {len(settings)}: refine the runs it trained")
    runs = checked_runs(train_set, targets, settings, camera, device, history.theta[-1], "fast", param_index,
                         row_rate)
    train_set, settings, camera, rows, row_rate = runs.train_set, runs.settings, runs.camera, runs.rows, runs.row_rate
    own_targets, theta = runs.own_targets, runs.starts
    passes = [replace(one, n_epoch=1, rule=refinement.rule,
                      depth_zoom=one.zoom if refinement.moves_c else one.depth_zoom) for one in settings]
    common = passes[0]
    per_epoch = len(train_set) // common.batch_size
    epochs_per_pass = -(-refinement.pass_steps // per_epoch)
    orders = shufflings([refine_seed(one.seed) for one in settings], len(train_set),
                         refinement.passes * epochs_per_pass)
    rates, widths = refinement.rates(common), refinement.widths
    whole = refinement.pass_steps % per_epoch == 0  # no step cut: every pass in one program
    programs = [range(refinement.passes)] if whole else [range(i, i + 1) for i in range(refinement.passes)]
    thetas, losses = [], []
    for program in programs:
        epochs = [i * epochs_per_pass + j for i in program for j in range(epochs_per_pass)]
        with tqdm(total=0, disable=True) as bar:
            steps, step_losses = train_steps(train_set, targets, own_targets, passes, camera, "fast",
                                                [common.zoom] * len(epochs), [rates[i // epochs_per_pass] for i in epochs],
                                                orders[epochs], theta, bar, rows, 1, row_rate,
                                                [widths[i // epochs_per_pass] for i in epochs])
        kept = len(program) * refinement.pass_steps  # the steps of the program's passes; the rest are cut
        thetas.append(steps[1 : kept + 1].cpu())
        losses.append(step_losses[:kept].cpu())
        theta = steps[kept]
    step_rates = torch.tensor(rates, dtype=torch.float64, device="cpu").repeat_interleave(refinement.pass_steps)
    recorded = torch.arange(1, refinement.steps + 1, dtype=torch.int64, device="cpu") + int(history.theta_steps[-1])
    check_divergence(torch.cat(thetas), recorded, torch.cat((history.lr, step_rates)), runs)
    return RunsHistory(torch.cat((history.theta, *thetas)), torch.cat((history.loss, *losses)),
                       torch.cat((history.zoom, torch.full((refinement.steps,), common.zoom, dtype=torch.int64))),
                       torch.cat((history.lr, step_rates)), settings, torch.cat((history.theta_steps, recorded)))

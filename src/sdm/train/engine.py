"""The training engine: :func:`train_runs` trains ``R`` independent runs as one program, :func:`train` is it with
``R = 1`` (paper, section 6; docs/method/paper.md, "Training and evaluation").

theta starts at (0, 0). For each zoom ``s, s-1, ..., zoom``: ``n_epoch`` passes over the training set in shuffled
mini-batches of 16 configurations (the incomplete last batch is dropped), the loss taken at that zoom; the learning
rate halves after each zoom. The loss is the *sum* over all points of the batch, which is what the paper's learning
rates assume.

On the CPU, for a rule with a compiled form (:attr:`sdm.mapping.rules.Rule.compiled`: ``"paper"``,
``"closed_centred_r1"``, ``"group_crossing"``) on float64 points, the whole run (every zoom, epoch, mini-batch, chain,
flow and SGD step) is one call of the compiled kernel (:func:`sdm.mapping.native.train_program`); everything else, and
every device, runs the torch path (:mod:`sdm.train.torch_path`), one layer call per step with autograd. Both give the
theta history of the single-run loop kept in ``tests/train_reference.py`` to the bit.
"""
from __future__ import annotations

from typing import Sequence

import torch
from tqdm.std import tqdm  # plain text: renders in notebooks without ipywidgets, no IProgress warning

from ..batch import ConfigurationSet
from ..camera import Camera
from ..errors import SDMInputError
from ..mapping import native
from ..mapping.crossing import rigid_groups
from ..mapping.rules import RULES, KernelFlow
from ..zoom import target_pyramid
from .checks import check_divergence, checked_row_zoom, checked_runs
from .settings import History, RunsHistory, TrainSettings
from .torch_path import train_torch


def train(
    train_set: ConfigurationSet,
    settings: TrainSettings = TrainSettings(),
    camera: Camera | None = None,
    progress: bool = True,
    method: str = "fast",
    theta0: tuple[float, ...] = (0.0, 0.0),
    device: torch.device | str | None = None,
) -> History:
    """Recover the shift from a training set: :func:`train_runs` with one run (``R = 1``).

    Args:
        train_set: packed configurations (points ``Q`` and targets ``L``).
        settings: hyper-parameters.
        camera: camera and screen; default the set's own.
        progress: show a progress bar.
        method: SDM implementation, ``"fast"`` or ``"dense"``.
        theta0: starting shift ``(a, b)`` (or ``(a, b, c)`` with ``fit_depth``) in metres.
        device: where to train (``"cpu"``, ``"cuda"``, ...); default the set's device.
            The shuffling is drawn on the CPU from ``settings.seed`` whatever the
            device, so every device trains on the same mini-batches.

    Returns:
        :class:`History` (on the CPU).

    >>> from sdm import ConfigurationSet, build_configuration, distance
    >>> from sdm.experiments.data.synthetic import synthetic_images
    >>> images = synthetic_images(32)  # the default synthetic data's first 32 images: car centres, metres
    >>> data = ConfigurationSet.from_configurations([build_configuration(image.centres) for image in images])
    >>> history = train(data, TrainSettings(n_epoch=2), progress=False)
    >>> history.theta.shape  # (steps + 1, 2): 5 zooms of 2 epochs of 2 batches of 16
    torch.Size([21, 2])
    >>> round(distance(history.final_theta), 2)  # metres from SKY_SHIFT
    0.02
    """
    runs = train_runs(train_set, [train_set.targets], [settings], camera, device, theta0=[theta0], method=method,
                      progress=progress)
    return History(runs.theta[:, 0].contiguous(), runs.loss[:, 0].contiguous(), runs.zoom, runs.lr, settings)


def train_runs(
    train_set: ConfigurationSet,
    targets: Sequence[torch.Tensor],
    settings: Sequence[TrainSettings],
    camera: Camera | None = None,
    device: torch.device | str | None = None,
    *,
    theta0: Sequence[Sequence[float]] | torch.Tensor | None = None,
    method: str = "fast",
    progress: bool = False,
    param_index: torch.Tensor | None = None,
    row_rate: torch.Tensor | None = None,
    row_zoom: torch.Tensor | None = None,
) -> RunsHistory:
    """``R`` independent training runs on the same points as one program: the one training engine.

    Run ``r`` trains on the points of ``train_set`` with its own targets ``targets[r]``,
    its own shuffling (``settings[r].seed``) and its own start ``theta0[r]``; runs never
    interact. :func:`train` is this with ``R = 1``. Two paths, the same theta histories:

    * **compiled** (CPU, float64 points, ``method="fast"``, a flow with a compiled form
      (:meth:`sdm.mapping.rules.Rule.kernel_flows`), no ``fit_depth``, the kernel of :mod:`sdm.mapping.native`
      available): Python draws every epoch's shuffling and zooms out every run's targets
      once, and one C call (``sdm_train``) does every zoom, epoch, mini-batch, chain,
      flow, loss and SGD step, with the torch path's float operations in its order:
      every run's theta history equals the torch path's to the bit
      (``tests/mapping/test_native.py``); only the loss is summed in another order (equal to
      1e-12 relative).
    * **torch** (everything else: CUDA, other rules, ``fit_depth``, ``"dense"``, no
      kernel): each step packs the ``R`` runs' mini-batches as ``R x batch_size``
      configurations of one layer call, run ``r``'s points moved by its own theta;
      autograd sums the flow per run. Flows are sums of signs, exact in float64 in
      any order, so each run's theta history equals the single-run loop of
      ``tests/train_reference.py`` to the bit (``test_train.py``). With ``fit_depth``
      theta is ``(R, 3)`` and each run's ``c`` is moved by its own depth flow
      (:mod:`sdm.depth`); that flow is a float sum, which packed runs may round
      differently: within 1e-12 m of the reference (``test_depth.py``), to the bit for ``R = 1``.

    **Parameters attached to points** (``param_index``; the paper's fundamental problem): theta is ``K``
    rows ``(a, b)`` per run, and point ``i`` is moved by the sum of its rows ``param_index[i]`` (one column:
    one row per point, e.g. one per configuration or one per car; two: a camera row shared by many points
    plus a residual row). A row's flow is the sum of its points' flows, and one SGD step moves every row by
    its own flow. ``param_index=None`` is the paper's case, ``K = 1`` row shared by every point (the
    shift ``(a, b)``): the same engine, whose histories are unchanged. Both paths take it (the compiled one
    moves each point by its rows' sum in the kernel); flows are exact sums, so both give every row the history
    of the plain single-run loop of ``tests/train_reference.py`` to the bit (``tests/train/test_param_index.py``).

    Args:
        train_set: packed configurations; their own targets are not used (pass ``train_set.targets``
            to train on them: its zoomed-out pyramid is then the set's cached one).
        targets: ``R`` tensors ``(N, H, W)`` bool, run ``r``'s training targets.
        settings: ``R`` settings; all fields but ``seed`` must agree (one learning-rate schedule,
            one ``rule``, one ``fit_depth``, ``depth_lr_scale`` and ``depth_zoom``).
        camera: camera and screen; default the set's own.
        device: where to train; default the set's device. The shuffling is drawn on the CPU.
        theta0: ``None`` (every run starts at zero) or ``R`` starts ``(a, b)`` (``(a, b, c)``, or
            ``(a, b)`` meaning ``c = 0``, with ``fit_depth``), metres; with ``param_index``, ``R`` starts
            ``(K, 2)``.
        method: SDM implementation, ``"fast"`` or ``"dense"`` (the grid reference: one run only).
        progress: show a progress bar.
        param_index: ``None`` (one shift for every point) or ``(P,)`` / ``(P, G)`` integer tensor over the
            set's ``P`` points: the rows of theta that move each point (see above; any device: it is moved to
            the set's). Every row ``0 .. K-1`` must move some point (``K = max + 1``).
        row_rate: ``None`` or ``(K,)`` positive factors, row ``k``'s step ``rate * row_rate[k] * flow_k`` (with
            ``param_index``): a row of few points gets a flow of few terms, and one rate for rows of 20 and of
            2,000 points moves the first too little or the second too far (:func:`rates_per_point`).
        row_zoom: ``None`` (every row trains at every zoom) or ``(K,)`` integers in ``zoom .. s`` (with
            ``param_index``), each row's first (coarsest) trained zoom: row ``k`` stays where it is at the zooms
            above ``row_zoom[k]`` (:func:`sdm.experiments.gate.prior_zooms`).

    Returns:
        :class:`RunsHistory` (on the CPU).

    Raises:
        SDMInputError: naming the argument, for mismatched runs, targets or starts, a set smaller than one
            batch, an unusable ``device``, a theta that became non-finite or ended beyond :data:`THETA_BOUND`
            (naming the run, the step and the setting), a start beyond it, a run whose every point is off the screen, a
            target set without an active pixel (docs/library.md, "Divergence"), or a
            ``param_index`` that is not an integer tensor of ``P`` rows, holds a negative entry, leaves a row
            with no point, or comes with ``fit_depth`` or ``method="dense"``.

    >>> import torch
    >>> from sdm import ConfigurationSet, add_target_noise, build_configuration, distance
    >>> from sdm.experiments.data.synthetic import synthetic_images
    >>> images = synthetic_images(32)  # the default synthetic data's first 32 images: car centres, metres
    >>> data = ConfigurationSet.from_configurations([build_configuration(image.centres) for image in images])
    >>> noisy = add_target_noise(data.targets, 2, torch.Generator().manual_seed(1))  # Table 2's noise, level 2
    >>> runs = train_runs(data, [data.targets, noisy], [TrainSettings(n_epoch=2, seed=0), TrainSettings(n_epoch=2, seed=1)])
    >>> runs.theta.shape  # (steps + 1, R, 2)
    torch.Size([21, 2, 2])
    >>> [round(distance(theta), 2) for theta in runs.final_theta]  # noise-free, noisy: metres from SKY_SHIFT
    [0.02, 0.03]
    """
    runs = checked_runs(train_set, targets, settings, camera, device, theta0, method, param_index, row_rate)
    train_set, settings, common, rows, starts = runs.train_set, runs.settings, runs.common, runs.rows, runs.starts
    n_configs, batch_size = len(train_set), common.batch_size
    first_zooms = checked_row_zoom(row_zoom, rows, common)

    zooms = list(range(common.s, common.zoom - 1, -1))
    rates, rate = [], common.lr
    for _ in zooms:  # the learning rate of each zoom: lr, then lr_decay times the last
        rates.append(rate)
        rate *= common.lr_decay
    # Every epoch's shuffling of every run, (zooms * n_epoch, R, N): each run's generator draws its
    # permutations in epoch order, as the run alone would.
    orders = shufflings([one.seed for one in settings], n_configs, len(zooms) * common.n_epoch)
    steps_per_zoom = common.n_epoch * (n_configs // batch_size)
    total = len(zooms) * steps_per_zoom
    step_zooms = torch.tensor(zooms, dtype=torch.int64, device="cpu").repeat_interleave(steps_per_zoom)
    step_rates = torch.tensor(rates, dtype=torch.float64, device="cpu").repeat_interleave(steps_per_zoom)

    record_every = 1 if rows is None else n_configs // batch_size  # rows: after every epoch
    with tqdm(total=total, disable=not progress, desc="SDM training", unit="step", leave=False) as bar:
        thetas, losses = train_steps(train_set, targets, runs.own_targets, settings, runs.camera, method, zooms,
                                        rates, orders, starts, bar, rows, record_every, runs.row_rate,
                                        row_zoom=first_zooms)
    theta_steps = torch.arange(0, total + 1, record_every, dtype=torch.int64, device="cpu")
    check_divergence(thetas.cpu(), theta_steps, step_rates, runs)
    return RunsHistory(thetas.cpu(), losses.cpu(), step_zooms, step_rates, settings, theta_steps)


def shufflings(seeds: Sequence[int], n_configs: int, n_epochs: int) -> torch.Tensor:
    """``(n_epochs, R, N)`` int64 CPU: each run's generator (seeded ``seeds[r]``) draws its permutations in
    epoch order, as the run alone would."""
    generators = [torch.Generator(device="cpu").manual_seed(int(seed)) for seed in seeds]
    return torch.stack([torch.stack([torch.randperm(n_configs, generator=g, device="cpu") for g in generators])
                        for _ in range(n_epochs)])


def run_pyramids(train_set: ConfigurationSet, targets: Sequence[torch.Tensor], own_targets: Sequence[bool],
                  steps: int) -> list[list[torch.Tensor]]:
    """Run r's zoomed-out targets, zooms 0..steps, on the set's device (the set's cached pyramid for its own)."""
    return [train_set.pyramid(steps) if own else target_pyramid(run_targets.to(train_set.device), steps)
            for own, run_targets in zip(own_targets, targets)]


def kernel_targets(train_set: ConfigurationSet, target: torch.Tensor, own: bool, steps: int,
                    zooms: list[int]) -> list[torch.Tensor | None]:
    """One run's target at each loss zoom for the compiled trainer (:func:`sdm.mapping.native.train_program`).

    ``target`` ``(N, H, W)`` bool is the run's. The set's cached pyramid's where ``own``; else ``target``
    at zoom 0 and ``None`` above it, where the kernel zooms ``target`` out itself (no torch pyramid is made).
    A rule's prepared target (``closed_centred_r1``'s closing) is the kernel's own work.
    """
    pyramid = train_set.pyramid(steps) if own else None
    return [pyramid[zoom] if pyramid is not None else (target if zoom == 0 else None) for zoom in zooms]


def train_steps(train_set, targets, own_targets, settings, camera, method, zooms, rates, orders, starts, bar,
                   rows=None, record_every=1, row_rate=None, widths=None, row_zoom=None):
    """The steps of :func:`train_runs` at ``zooms`` (``settings[0].n_epoch`` epochs each, rates ``rates``,
    shufflings ``orders``) from ``starts``, on the compiled path where it applies, else the torch path:
    ``(thetas (steps / record_every + 1, R, ...), losses (steps, R))`` on the set's device. ``rows``: ``None``
    or the checked ``(P, G)`` param_index (:func:`check_param_index`), ``row_rate`` ``None`` or its rows' rates,
    ``row_zoom`` ``None`` or its rows' first zooms (checked, :func:`checked_row_zoom`); ``widths``: ``None``
    or, per entry of ``zooms``, ``group_crossing``'s kernel half-width there (metres; :attr:`Refinement.widths`)."""
    common = settings[0]
    device = train_set.device
    row_rate = zoom_row_rates(zooms, row_rate, row_zoom, rows)
    rule = RULES.resolve(common.rule)
    windows = rule.kernel_flows(zooms)  # None: no compiled form
    if not (method == "fast" and not common.fit_depth and windows is not None and device.type == "cpu"
            and train_set.points.dtype == torch.float64 and native.enabled()
            and native.trains_screen(camera.screen_shape)):
        # the compiled groups split by rows; the torch rule cannot
        if rows is not None and windows is not None and KernelFlow.CROSSING in windows:
            check_rigid_rows(train_set, rows)
        pyramids = run_pyramids(train_set, targets, own_targets, common.s)  # run r's zooms 0..s
        return train_torch(train_set, pyramids, settings, camera, method, zooms, rates, orders, starts, bar,
                            rows, record_every, row_rate, widths)
    bases = [run_targets.to(device) for run_targets in targets]
    zoomed = [kernel_targets(train_set, base, own, common.s, zooms) for base, own in zip(bases, own_targets)]
    thetas, losses, failed = native.train_program(
        train_set.points, train_set.pixels, train_set.rank, train_set.offsets, camera, common.s, zooms,
        common.n_epoch, common.batch_size, rates, windows, orders, zoomed, starts, bases, rows, record_every,
        row_rate, widths)
    if bool((failed >= 0).any()):
        step = int(failed[failed >= 0].min())
        run = int((failed == step).nonzero()[0])
        rate = rates[step // (common.n_epoch * (len(train_set) // common.batch_size))]
        raise SDMInputError(f"theta of run {run} became non-finite at step {step + 1} (lr {rate!r} too large?)")
    bar.update(losses.shape[0])
    return thetas, losses


def zoom_row_rates(zooms: list[int], row_rate: torch.Tensor | None, row_zoom: torch.Tensor | None,
                   rows: torch.Tensor | None) -> torch.Tensor | None:
    """``(L, K)`` float64 each row's factor on each entry of ``zooms``' rate, on ``rows``' device: ``row_rate``
    (``(K,)``, or ones) at every zoom, times 0 at the zooms above the row's first zoom ``row_zoom`` (``(K,)``
    int64 CPU). ``None`` where both are ``None``."""
    if row_rate is None and row_zoom is None:
        return None
    n_rows = int(row_zoom.shape[0]) if row_zoom is not None else int(row_rate.shape[0])
    base = row_rate if row_rate is not None else torch.ones(n_rows, dtype=torch.float64, device=rows.device)
    per_zoom = base.unsqueeze(0).expand(len(zooms), n_rows)
    if row_zoom is None:
        return per_zoom.contiguous()
    trains = row_zoom.unsqueeze(0) >= torch.tensor(zooms, dtype=torch.int64).unsqueeze(1)  # (L, K)
    return per_zoom * trains.to(base.device, base.dtype)


def check_rigid_rows(train_set: ConfigurationSet, rows: torch.Tensor) -> None:
    """:class:`SDMInputError` naming ``param_index`` where a rigid group of ``group_crossing`` (the points of one
    configuration at one depth, :func:`sdm.mapping.crossing.rigid_groups`) holds points of different rows, on the
    torch path: its rule moves each group as one, which then would not be one shift. (The compiled trainer splits
    such groups by rows.)"""
    if rows.shape[0] == 0:
        return
    config = torch.repeat_interleave(torch.arange(len(train_set), device=train_set.device), train_set.counts)
    group, first = rigid_groups(train_set.points[:, :2], train_set.points[:, 2], config)
    differs = (rows != rows.index_select(0, first.index_select(0, group))).any(1)
    if bool(differs.any()):
        point = int(differs.nonzero()[0])
        raise SDMInputError(f"param_index: group_crossing moves the points of one configuration at one depth as "
                            f"one, but point {point} of configuration {int(config[point])} has rows "
                            f"{rows[point].tolist()} and another point at its depth has others")

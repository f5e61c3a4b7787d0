"""The paper's experiments as functions: the train/dev split, a tuning cell, a noise run.

The workflow's notebooks narrate and call these; nothing here is specific to
Snakemake. Every random choice takes an explicit seed, so a stage gives the
same numbers whenever and wherever it runs:

- the image sample is :func:`sdm.data.sample_indices` (the data layer's, which
  :func:`sdm.data.build_sky_dataset` uses too); the split uses a ``torch.Generator``
  seeded with the config's seed;
- the seed flows one way: the experiment's seed is ``settings.seed``; noise run
  ``run`` at ``level`` trains with :func:`run_seed` ``(settings.seed, level, run)``,
  which fixes both the noise drawn on its training targets and the shuffling of
  its mini-batches (and is reported in its row).
"""
from __future__ import annotations

from dataclasses import asdict, replace
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd
import torch

from .batch import ConfigurationSet
from .camera import APOLLO_CAMERA_5, Camera
from .data import SkyFile
from .errors import SDMInputError
from .mapping import SpatialDomainMapping
from .metrics import dev_loss, distance
from .sky import SKY_SHIFT, add_target_noise, shift_vector
from .train import TrainSettings, train, train_runs

#: Noise runs trained together by default (see :func:`noise_runs`). On one CPU core larger groups
#: stop paying: with the compiled kernel (:mod:`sdm.mapping.native`) the chain costs per point, and
#: groups of 8 or 16 runs were slower per run than groups of 4 (working set out of the core's cache;
#: benchmarks/bench_sdm.py measures it).
NOISE_GROUP_SIZE = 4


def run_seed(seed: int, level: int, run: int) -> int:
    """The seed of noise run ``run`` at ``level``: a hash of the three, stable across platforms."""
    for name, value in (("seed", seed), ("level", level), ("run", run)):
        if isinstance(value, bool) or int(value) != value or value < 0:
            raise SDMInputError(f"{name} must be a non-negative integer, got {value!r}")
    state = np.random.SeedSequence([int(seed), int(level), int(run)]).generate_state(1, dtype=np.uint32)
    return int(state[0])


def split_indices(n_total: int, n_train: int, n_dev: int, seed: int) -> dict[str, list[int]]:
    """Choose ``n_train + n_dev`` of ``range(n_total)`` at random and split them.

    Returns:
        ``{"selected", "train", "dev"}``: index lists; ``selected`` is sorted, ``train`` and
        ``dev`` are in random order (train first ``n_train`` of a random permutation).
    """
    n_selected = n_train + n_dev
    if n_train < 1 or n_dev < 1 or n_selected > n_total:
        raise SDMInputError(f"cannot split {n_total} configurations into {n_train} train and {n_dev} dev")
    generator = torch.Generator().manual_seed(int(seed))
    chosen = torch.randperm(n_total, generator=generator)[:n_selected].tolist()
    return {"selected": sorted(chosen), "train": chosen[:n_train], "dev": chosen[n_train:]}


def load_split(sky_path: str | Path, split: dict, camera: Camera | None = None):
    """The train and dev :class:`~sdm.batch.ConfigurationSet` of a Sky file and a split.

    Args:
        sky_path: file written by :func:`sdm.data.write_sky_file`.
        split: dict with ``train`` and ``dev`` index lists (the split stage's JSON).
        camera: defaults to the Sky file's camera.

    Returns:
        ``(train_set, dev_set, camera)``.
    """
    sky = SkyFile(sky_path)
    camera = camera or sky.camera
    train_set = ConfigurationSet.from_configurations([sky[i] for i in split["train"]], camera)
    dev_set = ConfigurationSet.from_configurations([sky[i] for i in split["dev"]], camera)
    return train_set, dev_set, camera


def settings_for(n_epoch: int, lr: float, s: int, batch_size: int, lr_decay: float, seed: int):
    """:class:`~sdm.train.TrainSettings` from the config's values (zoom 0: train to full resolution).

    ``seed`` becomes ``settings.seed``: the shuffling seed of a tuning cell, and the
    experiment seed from which :func:`noise_run` derives each run's own seed.
    """
    return TrainSettings(lr=float(lr), n_epoch=int(n_epoch), batch_size=int(batch_size), s=int(s), zoom=0,
                         lr_decay=float(lr_decay), seed=int(seed))


def tune_cell(train_set, dev_set, settings, shift: Sequence[float] = SKY_SHIFT, camera: Camera = APOLLO_CAMERA_5):
    """Train one cell of the tuning grid and score it on the dev set.

    Returns:
        ``(record, history)``: the record holds the settings, ``dev_loss`` (mean false-positive
        pixels per dev configuration), ``train_loss`` (the same measure on the training
        configurations, at the same final theta: Table 1's tie-break, :func:`sdm.report.tables.best_index`),
        the final ``a``, ``b`` and ``distance`` (metres; reported, not used to choose);
        ``history`` is the training's :meth:`~sdm.train.History.to_frame`.
    """
    history = train(train_set, settings, camera=camera, progress=False)
    theta = history.final_theta
    record = asdict(settings) | {
        "dev_loss": float(dev_loss(dev_set, theta, s=settings.s, camera=camera)),
        "train_loss": float(dev_loss(train_set, theta, s=settings.s, camera=camera)),
        "a": float(theta[0]),
        "b": float(theta[1]),
        "distance": float(distance(theta, tuple(shift))),
        "steps": int(history.loss.numel()),
    }
    return record, history.to_frame()


def noisy_targets(targets: torch.Tensor, level: int, seed: int, active: torch.Tensor | None = None) -> torch.Tensor:
    """Every target moved by noise ``level`` (paper, section 5.2), drawn from ``seed``.

    ``active`` is ``targets.nonzero()`` where the caller has it (one clean set, many draws).
    """
    generator = torch.Generator().manual_seed(int(seed))
    return add_target_noise(targets, level, generator, active)  # one draw for all targets, in target order


def noise_run(train_set, level: int, run: int, settings: TrainSettings, shift: Sequence[float] = SKY_SHIFT,
              camera: Camera | None = None) -> dict:
    """One run of the robustness experiment: noisy training targets, train, distance to theta*.

    The single-run reference that :func:`noise_runs` must reproduce, run for run.

    Args:
        train_set: the training configurations (noise-free targets).
        level: noise level ``n`` (screen pixels).
        run: run index.
        settings: the tuned settings; ``settings.seed`` is the experiment's seed, from
            which the run's own seed :func:`run_seed` ``(settings.seed, level, run)`` is
            derived: it draws the noise and shuffles the mini-batches.
        shift: theta* ``(a, b)``, metres.
        camera: default the set's.

    Returns:
        ``{"level", "run", "seed", "a", "b", "distance"}`` (metres; ``seed`` is the run's seed).
    """
    seed_run = run_seed(settings.seed, level, run)
    noisy = train_set.with_targets(noisy_targets(train_set.targets, level, seed_run))
    history = train(noisy, replace(settings, seed=seed_run), camera=camera, progress=False)
    a, b = history.final_theta
    return _run_record(level, run, seed_run, (a, b), shift)


def _run_record(level: int, run: int, seed_run: int, theta, shift) -> dict:
    a, b = float(theta[0]), float(theta[1])
    return {"level": int(level), "run": int(run), "seed": seed_run, "a": a, "b": b,
            "distance": float(distance((a, b), tuple(shift)))}


def noise_runs(train_set, level: int, runs: Sequence[int], settings: TrainSettings,
               shift: Sequence[float] = SKY_SHIFT, camera: Camera | None = None,
               group_size: int = NOISE_GROUP_SIZE, device: torch.device | str | None = None) -> pd.DataFrame:
    """Several noise runs at one level, trained together as one program; one row each.

    Run ``r`` is exactly :func:`noise_run` ``(train_set, level, r, settings)``: the same
    seed :func:`run_seed` ``(settings.seed, level, r)``, hence the same noisy targets
    and the same shuffling; the runs are packed ``group_size`` at a time into one
    batch of ``group_size x batch_size`` configurations per step by
    :func:`sdm.train.train_runs`, each run's theta moved only by its own flow.
    ``test_train.py`` holds every run's result to :func:`noise_run`'s.

    Args:
        group_size: runs trained together (memory grows with it: each run keeps its
            own zoomed-out targets, about 22 MB per 512 configurations of 128 x 256).
        device: where to train; default the set's device.

    Returns:
        Columns :data:`RUN_COLUMNS`, one row per run, in the order of ``runs``.
    """
    if int(group_size) != group_size or group_size < 1:
        raise SDMInputError(f"group_size must be a positive integer, got {group_size!r}")
    runs = [int(run) for run in runs]
    seeds = [run_seed(settings.seed, level, run) for run in runs]
    active = train_set.targets.nonzero() if level else None  # every run moves the same clean pixels
    rows = []
    for first in range(0, len(runs), int(group_size)):
        group = range(first, min(first + int(group_size), len(runs)))
        targets = [noisy_targets(train_set.targets, level, seeds[i], active) for i in group]
        history = train_runs(train_set, targets, [replace(settings, seed=seeds[i]) for i in group], camera=camera,
                             device=device)
        rows += [_run_record(level, runs[i], seeds[i], theta, shift) for i, theta in zip(group, history.final_theta)]
    return pd.DataFrame.from_records(rows, columns=RUN_COLUMNS)


#: Columns of a noise-run table.
RUN_COLUMNS = ["level", "run", "seed", "a", "b", "distance"]


def flow_at_true_shift(train_set: ConfigurationSet, levels: Sequence[int], seed: int, s: int = 4,
                       shift: Sequence[float] = SKY_SHIFT, camera: Camera | None = None,
                       batch_size: int = 64, flow: str = "paper") -> pd.DataFrame:
    """The dynamic gradient flow *at* theta*, on each noise level's training targets (run 0's draw).

    Without noise theta* is a fixed point (the flow vanishes at every zoom level). With noisy
    targets it need not be: a non-zero mean flow at theta* is a pull that SGD follows past
    theta*, i.e. a bias of the noisy estimates, measured here instead of guessed.

    ``flow`` names the gradient rule measured (:data:`sdm.FLOW_RULES`, default the paper's).

    Returns:
        One row per (noise level, zoom): ``level, zoom, flow_a, flow_b`` (summed flow per
        training configuration; negative values push theta~ up) and ``unmatched`` (share of
        the points entering the zoom level that land on the grid in a block the target leaves empty).
    """
    camera = camera or train_set.camera
    theta = shift_vector(shift, train_set.points)
    rows = []
    for level in levels:
        noisy = train_set.with_targets(noisy_targets(train_set.targets, level, run_seed(seed, level, 0)))
        for zoom in range(s, -1, -1):
            layer = SpatialDomainMapping(camera, s=s, zoom=zoom, flow=flow)
            total = torch.zeros(2, dtype=torch.float64, device=train_set.device)
            entered = unmatched = 0
            for _, batch in noisy.batches(batch_size):
                result = layer(batch.points + theta, batch.pixels, batch.targets, batch.config, batch.rank).result
                total += result.flow.sum(0)
                entered += int(result.entered.sum())
                unmatched += int(result.missed.sum())
            rows.append({"level": int(level), "zoom": zoom, "flow_a": float(total[0]) / len(noisy),
                         "flow_b": float(total[1]) / len(noisy), "unmatched": unmatched / max(entered, 1)})
    return pd.DataFrame.from_records(rows, columns=["level", "zoom", "flow_a", "flow_b", "unmatched"])


def single_thread(threads: int = 1) -> None:
    """Keep a job on its own cores (``torch.set_num_threads``); the workflow runs jobs side by side."""
    torch.set_num_threads(max(1, int(threads)))


# -- beyond the paper (issue 12): Table 2 per gradient rule, and the shift with depth ----------------------

#: Columns of a depth-run table (:func:`depth_noise_runs`); lengths in metres.
DEPTH_RUN_COLUMNS = ["c_true", "level", "run", "seed", "a", "b", "c", "error_a", "error_b", "error_c",
                     "distance_ab", "distance"]


def rule_noise_runs(train_set, rule: str, level: int, runs: Sequence[int], settings: TrainSettings,
                    shift: Sequence[float] = SKY_SHIFT, camera: Camera | None = None,
                    group_size: int = NOISE_GROUP_SIZE, device: torch.device | str | None = None) -> pd.DataFrame:
    """Table 2's runs at one level trained with another gradient rule, one row each.

    :func:`noise_runs` with ``replace(settings, flow=rule)``: run ``r`` draws the same noisy
    targets and shuffling as Table 2's run ``r`` (:func:`run_seed` ``(settings.seed, level, r)``
    does not depend on the rule), so the comparison with the paper's rule is paired.

    Args:
        rule: a name of :data:`sdm.FLOW_RULES`.
        the rest: as :func:`noise_runs`.

    Returns:
        Columns ``flow`` (the rule) then :data:`RUN_COLUMNS`, in the order of ``runs``.
    """
    frame = noise_runs(train_set, level, runs, replace(settings, flow=rule), shift=shift, camera=camera,
                       group_size=group_size, device=device)
    frame.insert(0, "flow", rule)
    return frame


def depth_noise_runs(train_set, c: float, level: int, runs: Sequence[int], settings: TrainSettings,
                     shift: Sequence[float] = SKY_SHIFT, camera: Camera | None = None,
                     device: torch.device | str | None = None) -> pd.DataFrame:
    """The robustness experiment for the general shift ``theta* = (a*, b*, c)``: one row per run.

    The training set's targets are rebuilt for its points moved by ``(a*, b*, c)``
    (:func:`sdm.depth.depth_targets`); run ``r`` moves them by noise ``level`` drawn from
    :func:`run_seed` ``(settings.seed, level, r)`` (the draw of Table 2's run ``r``, applied to
    these targets), which also shuffles its mini-batches, and trains ``(a, b, c)`` from
    ``(0, 0, 0)`` with ``fit_depth`` (the rest of ``settings`` as given: flow rule,
    ``depth_lr_scale``). The runs train one at a time (:func:`sdm.train.train`).

    Args:
        train_set: the training configurations (their points ``Q``; their own targets are not used).
        c: the true depth shift ``c*``, metres (positive: farther from the camera).
        level: noise level ``n`` (screen pixels).
        runs: run indices.
        settings: the tuned settings; ``settings.seed`` is the experiment's seed.
        shift: ``(a*, b*)``, metres.
        camera: default the set's.
        device: where to train; default the set's device.

    Raises:
        SDMInputError: ``shift`` is not two numbers, ``c`` is not finite, or ``c`` moves a point on or
            behind the camera (message starting ``c = ``).

    Returns:
        Columns :data:`DEPTH_RUN_COLUMNS`: ``c_true``, ``level``, ``run``, ``seed`` (the run's),
        the fitted ``a, b, c``, the absolute errors ``error_a, error_b, error_c``, the distance in
        ``(a, b)`` (``distance_ab``, as Table 2's) and in ``(a, b, c)`` (``distance``), all in metres.
    """
    from .depth import depth_targets

    if len(shift) != 2:
        raise SDMInputError(f"shift must be (a, b), metres (c is its own argument), got {tuple(shift)!r}")
    truth = (float(shift[0]), float(shift[1]), float(c))
    if not all(np.isfinite(truth)):
        raise SDMInputError(f"the shift (a, b, c) must be finite, got {truth!r}")
    camera = camera or train_set.camera
    if len(train_set.points) and float(train_set.points[:, 2].min()) + truth[2] <= 0:
        raise SDMInputError(f"c = {truth[2]!r} m moves the nearest point (depth {float(train_set.points[:, 2].min()):.2f} m) "
                            f"on or behind the camera")
    clean = depth_targets(train_set, truth, camera)
    depth_settings = replace(settings, fit_depth=True)
    rows = []
    for run in (int(run) for run in runs):
        seed_run = run_seed(settings.seed, level, run)
        noisy = train_set.with_targets(noisy_targets(clean, level, seed_run))
        history = train(noisy, replace(depth_settings, seed=seed_run), camera=camera, progress=False, device=device)
        fitted = history.final_theta
        errors = [abs(value - true) for value, true in zip(fitted, truth)]
        rows.append({"c_true": truth[2], "level": int(level), "run": run, "seed": seed_run,
                     "a": fitted[0], "b": fitted[1], "c": fitted[2],
                     "error_a": errors[0], "error_b": errors[1], "error_c": errors[2],
                     "distance_ab": float(np.hypot(errors[0], errors[1])),
                     "distance": float(np.sqrt(sum(error ** 2 for error in errors)))})
    return pd.DataFrame.from_records(rows, columns=DEPTH_RUN_COLUMNS)

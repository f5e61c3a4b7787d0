"""The paired runs of the tables: the train/dev split, a tuning cell, the seeded noise runs of Tables 2, 4 and 5
(:mod:`sdm.experiments`)."""
from __future__ import annotations

from dataclasses import asdict, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import pandas as pd
import torch

from ..batch import ConfigurationSet
from ..camera import APOLLO_CAMERA_5, Camera
from .data import SkyFile
from ..depth import depth_targets
from ..errors import SDMInputError
from ..metrics import dev_loss, distance
from ..sky import SKY_SHIFT, NoiseBuffer, add_target_noise
from ..train import Refinement, TrainSettings, parse_schedule, refine_runs, train, train_runs


#: Runs packed into one :func:`sdm.train.train_runs` call by default (:func:`paired_runs`'s
#: ``group_size``). The group size changes no result of the paper's rule (flows are exact sums of
#: signs, so a run's theta is its single run's to the bit in any group); it trades memory for speed:
#: every run of a group holds its noisy targets and their zoom pyramid at once (about 22 MB per 512
#: configurations of 128 x 256), and one step packs the group's mini-batches into one layer call. On a
#: GPU that is what pays (one step of many runs costs about one run's step), so pass a larger group
#: there (a chunk of 30 runs of 512 configurations is about 0.7 GB). On a CPU the compiled kernel
#: (:mod:`sdm.mapping.native`) costs per point, not per operation, so packing buys little: groups of 4
#: were 1.3x faster per run than one run at a time, one group of 30 was 0.76x (working set out of the
#: core's cache; ``benchmarks/speed/bench_sdm.py``; again for 8 runs of 512 configurations at level 2, CPU
#: seconds: 4 1.21x, 8 1.19x). 4 is that measured optimum, and its memory is small.
NOISE_GROUP_SIZE = 4


def run_seed(seed: int, noise_level: int, run: int) -> int:
    """The seed of noise run ``run`` at ``noise_level``: a hash of the three, stable across platforms."""
    for name, value in (("seed", seed), ("noise_level", noise_level), ("run", run)):
        if isinstance(value, bool) or int(value) != value or value < 0:
            raise SDMInputError(f"{name} must be a non-negative integer, got {value!r}")
    state = np.random.SeedSequence([int(seed), int(noise_level), int(run)]).generate_state(1, dtype=np.uint32)
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
        sky_path: file written by :func:`sdm.experiments.data.write_sky_file`.
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
    experiment seed from which :func:`paired_runs` derives each run's own seed.
    """
    return TrainSettings(lr=float(lr), n_epoch=int(n_epoch), batch_size=int(batch_size), s=int(s), zoom=0,
                         lr_decay=float(lr_decay), seed=int(seed))


def tuned_training(sky_path: str | Path, split: dict, best: dict, s: int, batch_size: int, lr_decay: float, seed: int):
    """What Table 2's runs (and Tables 4-5's) train on and with: ``(train_set, camera, settings)``, the split's
    training configurations of the Sky file (:func:`load_split`) and Table 1's chosen cell (``best``, the best
    stage's JSON: ``n_epoch``, ``lr``) with the config's other training values (:func:`settings_for`)."""
    train_set, _, camera = load_split(sky_path, split)
    return train_set, camera, settings_for(best["n_epoch"], best["lr"], s, batch_size, lr_decay, seed)


def tune_cell(train_set, dev_set, settings, shift: Sequence[float] = SKY_SHIFT, camera: Camera = APOLLO_CAMERA_5):
    """Train one cell of the tuning grid and score it on the dev set.

    Returns:
        ``(record, history)``: the record holds the settings, ``dev_loss`` (mean false-positive
        pixels per dev configuration), ``train_loss`` (the same measure on the training
        configurations, at the same final theta: Table 1's tie-break, :func:`sdm.experiments.report.tables.best_index`),
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


def noisy_targets(targets: torch.Tensor, noise_level: int, seed: int, active: torch.Tensor | None = None,
                  out: NoiseBuffer | None = None) -> torch.Tensor:
    """Every target moved by noise ``noise_level`` (paper, section 5.2), drawn from ``seed``.

    ``active`` is ``targets.nonzero()`` where the caller has it (one clean set, many draws); ``out`` a
    :class:`sdm.sky.NoiseBuffer` to draw into (as :func:`sdm.sky.add_target_noise`'s).
    """
    generator = torch.Generator().manual_seed(int(seed))
    return add_target_noise(targets, noise_level, generator, active, out)  # one draw for all targets, in target order


#: Columns of Table 2's run rows (:func:`noise_runs`); lengths in metres, ``seed`` the run's own.
#: Table 3's (:data:`sdm.experiments.baselines.RUN_COLUMNS`) and Table 4's (:func:`rule_noise_runs`) are built on it.
RUN_COLUMNS = ["noise_level", "run", "seed", "a", "b", "distance"]


def paired_runs(clean_targets: torch.Tensor, noise_level: int, runs: Sequence[int], seed: int,
                fit_group: Callable[[list[torch.Tensor], list[int]], Sequence], record: Callable[[object], dict],
                columns: Sequence[str], group_size: int | None = NOISE_GROUP_SIZE) -> pd.DataFrame:
    """The paired runs of every table (2, 3, 4, 5) at one noise level, one row each.

    The one place where runs get their seeds, their noisy targets and their groups: run ``r`` has
    the seed :func:`run_seed` ``(seed, level, r)`` and the targets :func:`noisy_targets`
    ``(clean_targets, level, that seed)``, whatever the table or the method, so every table's run
    ``(level, r)`` sees the same noise (the comparisons are paired). The runs go to ``fit_group``
    ``group_size`` at a time, in the order of ``runs``. The noisy targets a group gets are valid
    during its ``fit_group`` call only: the next group's are drawn into the same ``group_size``
    buffers (fresh 16 MB tensors per run cost more in first touches of their pages than the draw),
    and at level 0 (no noise: nothing moves) every run gets ``clean_targets`` itself, read-only.

    Args:
        clean_targets: ``(N, H, W)`` bool noise-free targets of the training configurations (any device).
        level: noise level ``n`` (screen pixels).
        runs: run indices (non-negative integers).
        seed: the experiment's seed.
        fit_group: ``fit_group(targets, seeds)``: a group's ``(N, H, W)`` bool noisy targets (on the
            device of ``clean_targets``; read-only, and not to be kept past the call) and their run
            seeds -> one result per run, in order.
        record: ``record(result)``: the row's columns beyond ``noise_level, run, seed``.
        columns: the table's columns, in order (:data:`RUN_COLUMNS`, ...).
        group_size: runs per ``fit_group`` call, a positive integer; ``None``: all of ``runs`` at once.

    Raises:
        SDMInputError: ``group_size`` is not a positive integer, or a run, the level or the seed is
            not a non-negative integer (naming it).

    Returns:
        ``columns``, one row per run, in the order of ``runs``.
    """
    if group_size is not None and (isinstance(group_size, bool) or int(group_size) != group_size or group_size < 1):
        raise SDMInputError(f"group_size must be a positive integer, got {group_size!r}")
    seeds = [run_seed(seed, noise_level, run) for run in runs]
    runs = [int(run) for run in runs]
    group_size = int(group_size) if group_size is not None else max(len(runs), 1)
    # Every run moves the same clean pixels; contiguous once (nonzero's rows are strided), not per draw.
    active = clean_targets.nonzero().contiguous() if noise_level else None
    buffers: list[torch.Tensor] = []  # the noisy targets' memory, drawn into again by every group
    rows = []
    for first in range(0, len(runs), group_size):
        group = range(first, min(first + group_size, len(runs)))
        if noise_level:
            buffers += [NoiseBuffer(clean_targets) for _ in range(len(group) - len(buffers))]
            noisy = [noisy_targets(clean_targets, noise_level, seeds[i], active, out)
                     for i, out in zip(group, buffers)]
        else:
            noisy = [clean_targets] * len(group)
        results = fit_group(noisy, [seeds[i] for i in group])
        del noisy
        rows += [{"noise_level": int(noise_level), "run": runs[i], "seed": seeds[i]} | record(result)
                 for i, result in zip(group, results)]
    return pd.DataFrame.from_records(rows, columns=list(columns))


def train_group(train_set: ConfigurationSet, targets: Sequence[torch.Tensor], settings: TrainSettings,
                seeds: Sequence[int], camera: Camera | None = None, device: torch.device | str | None = None,
                theta0=None, refine: Refinement | None = None):
    """SDM's fit of a group of paired runs: run ``r`` is ``settings`` with seed ``seeds[r]`` (its shuffling)
    on the points of ``train_set`` and the targets ``targets[r]``, all as one :func:`sdm.train.train_runs`
    (``theta0``: as there, ``None`` for every run from ``(0, 0)``).

    Table 2's, 4's and 5's runs (through :func:`paired_runs`) and SDM's rows of Table 3
    (:func:`sdm.experiments.baselines.sdm_layer.fit_runs`) all train here. ``refine``: the schedule's extra passes
    (:class:`sdm.train.Refinement`, :func:`sdm.train.refine_runs`), or ``None`` for the paper's coarse-to-fine training.

    Returns:
        :class:`sdm.train.RunsHistory` (on the CPU).
    """
    run_settings = [replace(settings, seed=int(seed)) for seed in seeds]
    history = train_runs(train_set, targets, run_settings, camera=camera, device=device, theta0=theta0)
    if refine is None:
        return history
    return refine_runs(train_set, targets, run_settings, history, refine, camera, device)


def shift_record(theta: Sequence[float], shift: Sequence[float]) -> dict:
    """The columns ``a, b, distance`` of a run that estimated ``theta = (a, b)`` (metres) against theta* ``shift``."""
    a, b = float(theta[0]), float(theta[1])
    return {"a": a, "b": b, "distance": float(distance((a, b), tuple(shift)))}


def noise_runs(train_set, noise_level: int, runs: Sequence[int], settings: TrainSettings,
               shift: Sequence[float] = SKY_SHIFT, camera: Camera | None = None,
               group_size: int = NOISE_GROUP_SIZE, device: torch.device | str | None = None,
               refine: Refinement | None = None) -> pd.DataFrame:
    """Table 2: noise runs at one level, trained ``group_size`` at a time as one program; one row each.

    Run ``r`` (:func:`paired_runs`) trains with the seed :func:`run_seed` ``(settings.seed, level, r)``,
    which draws its noisy targets and shuffles its mini-batches, from ``(0, 0)``; the runs of a group
    are packed by :func:`sdm.train.train_runs`, each run's theta moved only by its own flow, so each
    run's theta is what it would be trained alone, to the bit (``test_train.py`` holds it to the
    single-run reference of ``tests/run_reference.py``).

    Args:
        train_set: the training configurations (noise-free targets).
        level: noise level ``n`` (screen pixels).
        runs: run indices.
        settings: the tuned settings; ``settings.seed`` is the experiment's seed.
        shift: theta* ``(a, b)``, metres.
        camera: default the set's.
        group_size: runs trained together (:data:`NOISE_GROUP_SIZE`: the trade-off).
        device: where to train; default the set's device.
        refine: extra passes after the schedule (:class:`sdm.train.Refinement`), or ``None``.

    Returns:
        Columns :data:`RUN_COLUMNS`, one row per run, in the order of ``runs`` (metres).
    """
    return sdm_runs(train_set, train_set.targets, noise_level, runs, settings, lambda theta: shift_record(theta, shift),
                     RUN_COLUMNS, camera, group_size, device, refine)


def sdm_runs(train_set, clean_targets, noise_level, runs, settings, record, columns, camera, group_size, device,
              refine=None):
    """:func:`paired_runs` trained by SDM (:func:`train_group`): ``record`` gets a run's final theta."""
    def fit_group(targets, seeds):
        return train_group(train_set, targets, settings, seeds, camera, device, refine=refine).final_theta

    return paired_runs(clean_targets, noise_level, runs, settings.seed, fit_group, record, columns, group_size)


#: Columns of a depth-run table (:func:`depth_noise_runs`); lengths in metres.
DEPTH_RUN_COLUMNS = ["c_true", "noise_level", "run", "seed", "a", "b", "c", "error_a", "error_b", "error_c",
                     "distance_ab", "distance"]


def rule_noise_runs(train_set, rule: str, noise_level: int, runs: Sequence[int], settings: TrainSettings,
                    shift: Sequence[float] = SKY_SHIFT, camera: Camera | None = None,
                    group_size: int = NOISE_GROUP_SIZE, device: torch.device | str | None = None) -> pd.DataFrame:
    """Table 4: Table 2's runs at one level trained with another gradient rule or schedule, one row each.

    :func:`noise_runs` with ``replace(settings, rule=rule)`` (and its refinement): run ``r`` draws the same
    noisy targets and shuffling as Table 2's run ``r`` (:func:`run_seed` ``(settings.seed, level, r)``
    does not depend on the rule), so the comparison with the paper's rule is paired.

    Args:
        rule: a schedule (:func:`sdm.train.parse_schedule`): a rule name, or ``"RULE+REFINE:E"``.
        the rest: as :func:`noise_runs`.

    Returns:
        Columns ``rule`` (the schedule's name) then :data:`RUN_COLUMNS`, in the order of ``runs``.
    """
    first, refine = parse_schedule(rule)
    return sdm_runs(train_set, train_set.targets, noise_level, runs, replace(settings, rule=first),
                     lambda theta: {"rule": rule} | shift_record(theta, shift), ["rule", *RUN_COLUMNS], camera,
                     group_size, device, refine)


def depth_noise_runs(train_set, c: float, noise_level: int, runs: Sequence[int], settings: TrainSettings,
                     shift: Sequence[float] = SKY_SHIFT, camera: Camera | None = None,
                     group_size: int = NOISE_GROUP_SIZE, device: torch.device | str | None = None,
                     refine: Refinement | None = None) -> pd.DataFrame:
    """Table 5: the robustness experiment for the general shift ``theta* = (a*, b*, c)``, one row per run.

    The training set's targets are rebuilt for its points moved by ``(a*, b*, c)``
    (:func:`sdm.depth.depth_targets`); run ``r`` (:func:`paired_runs`) moves them by noise ``noise_level``
    drawn from :func:`run_seed` ``(settings.seed, level, r)`` (the draw of Table 2's run ``r``, applied
    to these targets), which also shuffles its mini-batches, and trains ``(a, b, c)`` from ``(0, 0, 0)``
    with ``fit_depth`` (the rest of ``settings`` as given: flow rule, ``depth_lr_scale``). The runs
    train ``group_size`` at a time (:func:`sdm.train.train_runs`). The depth flow is a float sum, not a
    sum of integer signs, so a packed run may round it differently than alone: each run's
    ``(a, b, c)`` is the single run's to 1e-12 m (``test_research.py``), and may move at that scale
    with ``group_size`` or with the runs it is grouped with.

    Args:
        train_set: the training configurations (their points ``Q``; their own targets are not used).
        c: the true depth shift ``c*``, metres (positive: farther from the camera).
        level: noise level ``n`` (screen pixels).
        runs: run indices.
        settings: the tuned settings; ``settings.seed`` is the experiment's seed.
        shift: ``(a*, b*)``, metres.
        camera: default the set's.
        group_size: runs trained together (as :func:`noise_runs`).
        device: where to train; default the set's device.
        refine: extra passes at zoom 0 after the schedule (:class:`sdm.train.Refinement`; with its default
            ``moves_c`` they move ``c`` too, which the schedule holds below ``settings.depth_zoom``), or ``None``.

    Raises:
        SDMInputError: ``shift`` is not two numbers, ``c`` is not finite, or ``c`` moves a point on or
            behind the camera (message starting ``c = ``).

    Returns:
        Columns :data:`DEPTH_RUN_COLUMNS`: ``c_true``, ``noise_level``, ``run``, ``seed`` (the run's),
        the fitted ``a, b, c``, the absolute errors ``error_a, error_b, error_c``, the distance in
        ``(a, b)`` (``distance_ab``, as Table 2's) and in ``(a, b, c)`` (``distance``), all in metres.
    """
    if len(shift) != 2:
        raise SDMInputError(f"shift must be (a, b), metres (c is its own argument), got {tuple(shift)!r}")
    truth = (float(shift[0]), float(shift[1]), float(c))
    if not all(np.isfinite(truth)):
        raise SDMInputError(f"the shift (a, b, c) must be finite, got {truth!r}")
    camera = camera or train_set.camera
    if len(train_set.points) and float(train_set.points[:, 2].min()) + truth[2] <= 0:
        raise SDMInputError(f"c = {truth[2]!r} m moves the nearest point (depth {float(train_set.points[:, 2].min()):.2f} m) "
                            f"on or behind the camera")

    def record(fitted) -> dict:
        errors = [abs(value - true) for value, true in zip(fitted, truth)]
        return {"c_true": truth[2], "a": fitted[0], "b": fitted[1], "c": fitted[2],
                "error_a": errors[0], "error_b": errors[1], "error_c": errors[2],
                "distance_ab": float(np.hypot(errors[0], errors[1])),
                "distance": float(np.sqrt(sum(error ** 2 for error in errors)))}

    return sdm_runs(train_set, depth_targets(train_set, truth, camera), noise_level, runs,
                     replace(settings, fit_depth=True), record, DEPTH_RUN_COLUMNS, camera, group_size, device, refine)


def single_thread(threads: int = 1) -> None:
    """Keep a job on its own cores (``torch.set_num_threads``); the workflow runs jobs side by side."""
    torch.set_num_threads(max(1, int(threads)))

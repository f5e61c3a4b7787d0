"""The compiled CPU kernel (sdm.mapping.native) against the torch path it replaces: equal to the bit."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from sdm.camera import APOLLO_CAMERA_5 as CAM
from sdm.mapping import native
from sdm.mapping.fast import _SCRATCH, fast_mapping
from sdm.mapping.research_rules import RESEARCH_RULES
from sdm.mapping.rules import FLOW_RULES
from sdm.representation import NO_RANK
from sdm.sky import shift_vector
from sdm.train import TrainSettings, train, train_runs
from sdm.zoom import zoom_out

from scenes import configuration_set

pytestmark = pytest.mark.skipif(not native.enabled(), reason="no C compiler: the compiled kernel is not built")

RULES = FLOW_RULES | RESEARCH_RULES  # the product's rules and the experiments
FIELDS = ("out_pixels", "flow", "loss", "entered", "matched", "landed")


def assert_same(kernel, reference):
    for field in FIELDS:
        mine, theirs = getattr(kernel, field), getattr(reference, field)
        assert mine.dtype == theirs.dtype and mine.shape == theirs.shape, field
        assert torch.equal(mine, theirs), f"{field} differs"


def batch_of(data, theta, dtype=torch.float64):
    batch = data.batch(torch.arange(len(data)))
    points = (batch.points + shift_vector(torch.as_tensor(theta, dtype=torch.float64), batch.points)).to(dtype)
    return points, batch


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("steps,zoom", [(4, 0), (4, 2), (4, 4), (3, 1), (2, 0)])
def test_kernel_equals_the_torch_path_bit_for_bit(seed, steps, zoom):
    data = configuration_set(12, seed=seed)
    generator = torch.Generator().manual_seed(seed)
    # From far off (points leave the screen, whole blocks collide) to close to the true shift.
    for theta in (torch.randn(2, generator=generator, dtype=torch.float64) * 3.0, (0.31, 0.22), (0.5, 0.3)):
        points, batch = batch_of(data, theta)
        target = zoom_out(data.targets, zoom)
        kernel = fast_mapping(points, batch.pixels, batch.config, batch.rank, target, steps, zoom, CAM)
        reference = fast_mapping(points, batch.pixels, batch.config, batch.rank, target, steps, zoom, CAM,
                                 native=False)
        assert_same(kernel, reference)
        assert bool(reference.missed.any()) or float(reference.loss) == 0.0


def test_kernel_leaves_the_scratch_buffer_clean():
    data = configuration_set(6, seed=4)
    points, batch = batch_of(data, (1.0, -0.5))
    fast_mapping(points, batch.pixels, batch.config, batch.rank, data.targets, 4, 0, CAM)
    buffer = _SCRATCH.buffers[torch.device("cpu")]
    assert bool((buffer == NO_RANK).all())


@pytest.mark.parametrize("rule", sorted(set(RULES) - {"paper"}))
def test_kernel_chain_with_every_other_rule_equals_the_torch_path(rule):
    data = configuration_set(8, seed=5)
    points, batch = batch_of(data, (0.2, 0.5))
    target = zoom_out(data.targets, 0)
    args = (points, batch.pixels, batch.config, batch.rank, target, 4, 0, CAM, RULES[rule])
    assert_same(fast_mapping(*args), fast_mapping(*args, native=False))


def test_float32_points_take_the_kernel_chain_and_the_torch_flow():
    data = configuration_set(8, seed=6)
    points, batch = batch_of(data, (0.4, 0.1), dtype=torch.float32)
    args = (points, batch.pixels, batch.config, batch.rank, data.targets, 4, 0, CAM)
    assert_same(fast_mapping(*args), fast_mapping(*args, native=False))


def test_non_contiguous_inputs_give_the_same_result():
    data = configuration_set(6, seed=7)
    points, batch = batch_of(data, (0.3, 0.3))
    pixels = batch.pixels.t().contiguous().t()  # same values, column-major
    assert not pixels.is_contiguous()
    kernel = fast_mapping(points, pixels, batch.config, batch.rank, data.targets, 4, 0, CAM)
    assert_same(kernel, fast_mapping(points, batch.pixels, batch.config, batch.rank, data.targets, 4, 0, CAM,
                                     native=False))


def assert_same_runs(compiled, reference_theta, reference_loss):
    """Theta histories to the bit; the loss (summed in another order) to 1e-12 relative."""
    assert torch.equal(compiled.theta, reference_theta)
    assert compiled.loss.shape == reference_loss.shape
    assert float((compiled.loss - reference_loss).abs().max()) <= 1e-12 * float(reference_loss.abs().max())


def test_training_with_the_kernel_equals_training_without():
    data = configuration_set(64, seed=8)
    settings = TrainSettings(lr=3e-4, n_epoch=1, batch_size=16, seed=3)
    with_kernel = train(data, settings, progress=False)
    runs_with = train_runs(data, [data.targets, data.targets], [settings, TrainSettings(lr=3e-4, n_epoch=1, seed=4)])
    with native.disabled():
        assert not native.enabled()
        without = train(data, settings, progress=False)
        runs_without = train_runs(data, [data.targets, data.targets],
                                  [settings, TrainSettings(lr=3e-4, n_epoch=1, seed=4)])
    assert native.enabled()
    assert_same_runs(with_kernel, without.theta, without.loss)
    assert_same_runs(runs_with, runs_without.theta, runs_without.loss)
    assert not torch.equal(with_kernel.theta[0], with_kernel.theta[-1])  # it trained


@pytest.fixture
def compiled_calls(monkeypatch):
    """Counts the calls of the compiled engine (so a test knows the whole run was compiled)."""
    calls = []
    original = native.train_program

    def spy(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(native, "train_program", spy)
    return calls


@pytest.mark.parametrize("rule", ["paper", "closed_centred_r1", "group_crossing"])
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("s,zoom,n_epoch", [(4, 0, 1), (3, 1, 2)])
def test_the_compiled_run_equals_the_reference_loop_bit_for_bit(rule, seed, s, zoom, n_epoch, compiled_calls):
    """One C call per program: R = 1 (train) and R = 3 (own noise, seeds, starts) against tests/train_reference.py."""
    from sdm.experiments import noisy_targets
    from train_reference import reference_train

    data = configuration_set(80, seed=10 + seed)
    base = TrainSettings(lr=3e-4, n_epoch=n_epoch, s=s, zoom=zoom, rule=rule)
    settings = [replace(base, seed=seed + k) for k in (0, 5, 9)]
    targets = [data.targets, noisy_targets(data.targets, 2, seed), noisy_targets(data.targets, 1, seed + 1)]
    starts = [(0.0, 0.0), (0.45, 0.2), (0.7, 0.5)]
    reference = [reference_train(data.with_targets(t), one, theta0=start)
                 for t, one, start in zip(targets, settings, starts)]
    alone = train(data.with_targets(targets[1]), settings[1], progress=False, theta0=starts[1])
    assert_same_runs(alone, *reference[1])
    together = train_runs(data, targets, settings, theta0=starts)
    assert len(compiled_calls) == 2
    for run, (theta, loss) in enumerate(reference):
        assert torch.equal(together.theta[:, run], theta), run
        assert float((together.loss[:, run] - loss).abs().max()) <= 1e-12 * float(loss.abs().max()), run
    assert not torch.equal(together.theta[0], together.theta[-1])


@pytest.mark.slow
def test_the_compiled_run_on_real_sized_data(compiled_calls):
    """512 configurations of the test scenes, Table 2's schedule (n_epoch 2, lr 1e-4), noisy targets, both rules."""
    from sdm.experiments import noisy_targets
    from train_reference import reference_train

    data = configuration_set(512, seed=2024)
    targets = [noisy_targets(data.targets, 2, 3), noisy_targets(data.targets, 4, 4)]
    finals = {}
    for rule in ("paper", "closed_centred_r1", "group_crossing"):
        settings = [TrainSettings(lr=1e-4, n_epoch=2, seed=seed, rule=rule) for seed in (6, 7)]
        compiled = train_runs(data, targets, settings)
        for run in range(2):
            theta, loss = reference_train(data.with_targets(targets[run]), settings[run])
            assert torch.equal(compiled.theta[:, run], theta), (rule, run)
            assert float((compiled.loss[:, run] - loss).abs().max()) <= 1e-12 * float(loss.abs().max())
        finals[rule] = compiled.theta[-1]
    assert len(compiled_calls) == 3
    assert not torch.equal(finals["paper"], finals["closed_centred_r1"])  # the rules differ at zoom 0
    assert not torch.equal(finals["paper"], finals["group_crossing"])


def test_the_compiled_closing_on_a_screen_of_odd_sides(compiled_calls):
    """closed_centred_r1's compiled closing on a screen whose sides are no powers of two: 200 x 72 (100 x 36, 50 x 18
    and 25 x 9 at the zooms above), its borders and odd widths closed as the reference's, so the run equals
    tests/train_reference.py's bit for bit."""
    from dataclasses import replace as replaced

    from scenes import road_centres
    from sdm.batch import ConfigurationSet
    from sdm.experiments import noisy_targets
    from sdm.sky import build_configuration
    from train_reference import reference_train

    camera = replaced(CAM, screen_height=72, screen_width=200)
    generator = torch.Generator().manual_seed(77)
    data = ConfigurationSet.from_configurations(
        [build_configuration(road_centres(generator, 12), camera=camera, image_id=f"odd{i}") for i in range(40)],
        camera=camera)
    assert data.targets.shape[1:] == (72, 200)
    settings = [TrainSettings(lr=3e-4, n_epoch=1, s=3, rule="closed_centred_r1", seed=seed) for seed in (1, 2)]
    targets = [noisy_targets(data.targets, 2, 5), noisy_targets(data.targets, 3, 6)]
    compiled = train_runs(data, targets, settings)
    assert len(compiled_calls) == 1
    for run in range(2):
        theta, _ = reference_train(data.with_targets(targets[run]), settings[run])
        assert torch.equal(compiled.theta[:, run], theta), run


@pytest.mark.slow
def test_other_training_settings_take_the_torch_path(compiled_calls):
    data = configuration_set(32, seed=12)
    for settings in (TrainSettings(rule="closed", s=2), TrainSettings(fit_depth=True, s=2)):
        train(data, settings, progress=False)
    train(data, TrainSettings(s=2, zoom=2), progress=False, method="dense")
    assert compiled_calls == []


def test_without_a_compiler_the_layer_warns_once_and_runs_the_torch_path(tmp_path):
    script = textwrap.dedent(
        """
        import warnings, torch
        from sdm.camera import APOLLO_CAMERA_5 as CAM
        from sdm.mapping import native
        from sdm.mapping.fast import fast_mapping
        from sdm.sky import shift_vector
        from scenes import configuration_set
        data = configuration_set(4, seed=9)
        batch = data.batch(torch.arange(4))
        points = batch.points + shift_vector(torch.tensor([0.3, 0.2], dtype=torch.float64), batch.points)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            first = fast_mapping(points, batch.pixels, batch.config, batch.rank, data.targets, 4, 0, CAM)
            fast_mapping(points, batch.pixels, batch.config, batch.rank, data.targets, 4, 0, CAM)
        messages = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
        assert len(messages) == 1 and "torch path" in messages[0], messages
        assert not native.enabled()
        reference = fast_mapping(points, batch.pixels, batch.config, batch.rank, data.targets, 4, 0, CAM,
                                 native=False)
        assert torch.equal(first.flow, reference.flow) and torch.equal(first.loss, reference.loss)
        print("ok")
        """
    )
    tests = Path(__file__).parents[1]
    env = os.environ | {"CC": str(tmp_path / "no-such-compiler"), "SDM_CACHE_DIR": str(tmp_path / "cache"),
                        "PYTHONPATH": os.pathsep.join([str(tests), str(Path(__file__).parent), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "ok"
    assert not any((tmp_path / "cache").glob("*")), "a failed build left a file behind"


@pytest.mark.slow
def test_the_kernel_is_built_once_into_the_cache_folder(tmp_path):
    env = os.environ | {"SDM_CACHE_DIR": str(tmp_path)}
    script = "from sdm.mapping import native; print(native.enabled())"
    for _ in range(2):
        done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
        assert done.stdout.strip() == "True", done.stderr
    library, checksum = sorted(tmp_path.iterdir(), key=lambda path: path.suffix != ".so")  # and nothing else
    assert library.name.startswith("sdm_native_") and library.suffix == ".so" and checksum.suffix == ".sha256"
    assert library.stat().st_mode & 0o044 == 0o044  # readable by others


def test_sdm_native_0_turns_the_kernel_off():
    env = os.environ | {"SDM_NATIVE": "0"}
    script = "from sdm.mapping import native; print(native.enabled())"
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert done.stdout.strip() == "False", done.stderr


def test_the_compiled_run_keeps_the_order_of_ranks_beyond_int32(compiled_calls):
    """The trainer's rmin tables hold int32: a set whose ranks do not fit is re-ranked by order within each
    configuration, and its run still equals the reference loop bit for bit. The ranks here order the points by
    rank % 3 first, a multiple of 2**33 that a plain cast to int32 would drop (leaving the reversed order)."""
    from sdm.batch import ConfigurationSet
    from train_reference import reference_train

    data = configuration_set(48, seed=31)
    far = ConfigurationSet(data.points, data.pixels, data.offsets, data.targets, data.camera,
                           rank=data.rank % 3 * 2**33 + (2**20 - data.rank))
    settings = TrainSettings(lr=3e-4, n_epoch=1, seed=2)
    compiled = train(far, settings, progress=False)
    theta, loss = reference_train(far, settings)
    assert len(compiled_calls) == 1
    assert_same_runs(compiled, theta, loss)
    assert not torch.equal(train(data, settings, progress=False).theta, compiled.theta)  # the order matters

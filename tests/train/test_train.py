import contextlib
import math
from dataclasses import replace

import pytest
import torch

from scenes import configuration_set
from sdm.errors import SDMInputError
from sdm.metrics import dev_loss, distance, false_positive_pixels
from sdm.sky import SKY_SHIFT
from sdm.train import TrainSettings, train


@pytest.fixture(scope="module")
def sky768():
    data = configuration_set(768, seed=2024)
    return data.subset(range(512)), data.subset(range(512, 768))


def test_recovers_the_shift_without_noise(sky768):
    """The acceptance criterion: 512 noise-free configurations, n_epoch = 1, lr = 3e-4 -> within 2e-3 m
    (paper: 0.68e-3)."""
    train_set, dev_set = sky768
    history = train(train_set, TrainSettings(lr=3e-4, n_epoch=1), progress=False)
    assert distance(history.final_theta) < 2e-3
    assert dev_loss(dev_set, history.final_theta) < dev_loss(dev_set, (0.0, 0.0))


def test_history_records_every_step(sky768):
    train_set, _ = sky768
    history = train(train_set.subset(range(100)), TrainSettings(lr=3e-4, n_epoch=2, s=3), progress=False)
    per_zoom = 2 * (100 // 16)  # incomplete last batch dropped
    assert history.theta.shape == (4 * per_zoom + 1, 2) and torch.equal(history.theta[0], torch.zeros(2, dtype=torch.float64))
    assert history.zoom.tolist() == [3] * per_zoom + [2] * per_zoom + [1] * per_zoom + [0] * per_zoom
    assert history.lr.unique().tolist() == sorted(3e-4 * 0.5**k for k in range(4))
    frame = history.to_frame()
    assert list(frame.columns) == ["step", "zoom", "lr", "loss", "a", "b"] and len(frame) == 4 * per_zoom
    assert (frame["a"].iloc[-1], frame["b"].iloc[-1]) == history.final_theta


def test_same_seed_same_run_other_seed_other_run(sky768):
    train_set, _ = sky768
    small = train_set.subset(range(64))
    first = train(small, TrainSettings(seed=1), progress=False)
    again = train(small, TrainSettings(seed=1), progress=False)
    other = train(small, TrainSettings(seed=2), progress=False)
    assert torch.equal(first.theta, again.theta)
    assert not torch.equal(first.theta, other.theta)


@pytest.mark.slow
def test_dense_training_follows_the_fast_path(sky768):
    train_set, _ = sky768
    small = train_set.subset(range(16))
    settings = TrainSettings(batch_size=8, s=4, zoom=2, seed=3)
    fast = train(small, settings, progress=False, method="fast")
    dense = train(small, settings, progress=False, method="dense")
    assert torch.allclose(fast.theta, dense.theta, rtol=0, atol=1e-12)


def test_empty_configurations_contribute_nothing(sky768):
    from sdm.batch import ConfigurationSet
    from sdm.sky import build_configuration

    train_set, _ = sky768
    empty = [build_configuration(torch.zeros(0, 3), image_id=f"empty{i}") for i in range(16)]
    mixed = ConfigurationSet.from_configurations(empty)
    history = train(mixed, TrainSettings(), progress=False)
    assert not bool(history.theta.any()) and not bool(history.loss.any())
    assert int(false_positive_pixels(mixed, SKY_SHIFT).sum()) == 0


def test_dev_loss_is_zero_at_the_true_shift(sky768):
    _, dev_set = sky768
    assert int(false_positive_pixels(dev_set, SKY_SHIFT).sum()) == 0
    assert dev_loss(dev_set, (0.3, 0.1)) > 0


def test_distance():
    assert distance((0.517, 0.303)) == 0
    assert distance((0.517 + 3e-3, 0.303 - 4e-3)) == pytest.approx(5e-3)


@pytest.mark.parametrize(
    "kwargs, message",
    [({"lr": 0.0}, "lr must be"), ({"lr": math.nan}, "lr must be"), ({"n_epoch": 0}, "n_epoch"),
     ({"batch_size": 2.5}, "batch_size"), ({"zoom": 5}, "zoom must be"), ({"s": -1}, "s must be")],
)
def test_bad_settings(kwargs, message):
    with pytest.raises(SDMInputError, match=message):
        TrainSettings(**kwargs)


def test_bad_training_input(sky768):
    train_set, _ = sky768
    with pytest.raises(SDMInputError, match="fewer than one batch"):
        train(train_set.subset(range(10)), progress=False)
    with pytest.raises(SDMInputError, match="theta0"):
        train(train_set.subset(range(16)), theta0=(math.nan, 0.0), progress=False)
    with pytest.raises(SDMInputError, match="not divisible"):
        train(train_set.subset(range(16)), TrainSettings(s=8, zoom=0), progress=False)


# -- many runs as one program ------------------------------------------------------------------

def test_runs_trained_together_follow_their_own_histories(sky768):
    """Each run of train_runs has train()'s theta history to the bit (flows are exact sums of signs)."""
    from sdm.experiments import noisy_targets
    from sdm.train import train_runs

    train_set, _ = sky768
    small = train_set.subset(range(48))
    base = TrainSettings(lr=3e-4, n_epoch=2, s=3)
    settings = [replace(base, seed=seed) for seed in (4, 9, 4)]
    targets = [small.targets, noisy_targets(small.targets, 2, 1), noisy_targets(small.targets, 1, 5)]
    together = train_runs(small, targets, settings)
    assert together.theta.shape == (len(together.loss) + 1, 3, 2) and together.loss.shape == (len(together.lr), 3)
    for run, (one, run_targets) in enumerate(zip(settings, targets)):
        alone = train(small.with_targets(run_targets), one, progress=False)
        assert torch.equal(together.theta[:, run], alone.theta), run
        assert torch.equal(together.loss[:, run], alone.loss), run  # the same engine: each run's own loss
    assert not torch.equal(together.theta[:, 0], together.theta[:, 2])  # same seed, other noise: other run
    assert torch.equal(together.lr, alone.lr) and torch.equal(together.zoom, alone.zoom)


@pytest.mark.parametrize("rule", ["paper", "closed_centred_r1", "closed"])
def test_the_torch_path_equals_the_reference_loop(sky768, rule):
    """The engine's torch path (what CUDA, other rules and a missing kernel run) against tests/train_reference.py.

    R = 1 (train) and R = 3 (noise, seeds and starts of their own): theta histories and each run's loss to the bit.
    """
    from sdm.experiments import noisy_targets
    from sdm.mapping import native
    from sdm.train import train_runs
    from train_reference import reference_train

    train_set, _ = sky768
    small = train_set.subset(range(64))
    base = TrainSettings(lr=2e-4, n_epoch=1, s=3, rule=rule)
    settings = [replace(base, seed=seed) for seed in (1, 7, 12)]
    targets = [noisy_targets(small.targets, level, seed) for level, seed in ((0, 0), (2, 3), (1, 8))]
    starts = [(0.0, 0.0), (0.4, 0.1), (-0.3, 0.6)]
    with native.disabled():
        alone = train(small.with_targets(targets[1]), settings[1], progress=False, theta0=starts[1])
        together = train_runs(small, targets, settings, theta0=starts)
    reference = [reference_train(small.with_targets(t), one, theta0=start)
                 for t, one, start in zip(targets, settings, starts)]
    assert torch.equal(alone.theta, reference[1][0]) and torch.equal(alone.loss, reference[1][1])
    for run, (theta, loss) in enumerate(reference):
        assert torch.equal(together.theta[:, run], theta), run
        assert torch.equal(together.loss[:, run], loss), run
    assert not torch.equal(reference[0][0], reference[2][0])


def test_non_finite_theta_names_the_run_and_the_step(sky768):
    """Run 1 blows up at its first step (huge lr); run 0 has all-active targets, is never pulled, stays finite."""
    from sdm.mapping import native
    from sdm.train import train_runs

    train_set, _ = sky768
    small = train_set.subset(range(32))
    settings = [TrainSettings(lr=1e308, s=2, seed=seed) for seed in (0, 1)]
    targets = [torch.ones_like(small.targets), small.targets]
    for compiled in (True, False):
        with contextlib.ExitStack() as stack:
            if not compiled:
                stack.enter_context(native.disabled())
            with pytest.raises(SDMInputError, match=r"theta of run 1 became non-finite at step 1 \(lr 1e\+308"):
                train_runs(small, targets, settings)
            with pytest.raises(SDMInputError, match="run 0 became non-finite at step 1"):
                train(small, settings[0], progress=False)


def test_an_unusable_device_is_an_input_error(sky768):
    """device="cuda" on a CPU-only torch names ``device`` (torch itself raises an AssertionError)."""
    if torch.cuda.is_available():
        pytest.skip("CUDA is available here")
    train_set, _ = sky768
    with pytest.raises(SDMInputError, match="device 'cuda'"):
        train(train_set.subset(range(16)), device="cuda", progress=False)
    with pytest.raises(SDMInputError, match="device 'nonsense'"):
        train(train_set.subset(range(16)), device="nonsense", progress=False)


def test_bad_starts(sky768):
    from sdm.train import train_runs

    train_set, _ = sky768
    small = train_set.subset(range(16))
    with pytest.raises(SDMInputError, match="one start per run"):
        train_runs(small, [small.targets] * 2, [TrainSettings()] * 2, theta0=[(0.0, 0.0)])
    with pytest.raises(SDMInputError, match=r"theta0\[1\] must be 2 finite numbers"):
        train_runs(small, [small.targets] * 2, [TrainSettings()] * 2, theta0=[(0.0, 0.0), (1.0, math.inf)])
    with pytest.raises(SDMInputError, match="one run at a time"):
        train_runs(small, [small.targets] * 2, [TrainSettings()] * 2, method="dense")


@pytest.mark.slow
@pytest.mark.parametrize("rule", ["paper", "closed_centred_r1", "normalised"])
def test_noise_runs_equal_single_noise_runs(sky768, rule):
    """Each batched run of Table 2 (the paper's rule) or Table 4 (another rule) is the run
    trained alone (tests/run_reference.py), to the bit where the rule's flow is a sum of signs (or of
    halves); normalised's weights are fractions, so packed sums may round otherwise: 1e-12 m."""
    from run_reference import noise_run
    from sdm.experiments import noise_runs, rule_noise_runs

    train_set, _ = sky768
    small = train_set.subset(range(64))
    settings = TrainSettings(lr=1e-4, n_epoch=2, seed=3)
    for level in (0, 2):
        if rule == "paper":
            table = noise_runs(small, level, [0, 1, 2, 5], settings, group_size=3)  # two groups: 3 runs, then 1
        else:
            table = rule_noise_runs(small, rule, level, [0, 1, 2, 5], settings, group_size=3)
            assert set(table.pop("rule")) == {rule}
        assert table["run"].tolist() == [0, 1, 2, 5]
        for row in table.to_dict("records"):
            alone = noise_run(small, level, row["run"], replace(settings, rule=rule))
            if rule == "normalised":
                assert all(abs(row[key] - alone[key]) <= 1e-12 for key in ("a", "b", "distance"))
                row |= {key: alone[key] for key in ("a", "b", "distance")}
            assert row == alone
        if level:
            assert table["a"].nunique() > 1  # the runs differ: each has its own noise and shuffling


def test_paired_runs_pack_group_size_runs_per_train_runs_call(sky768, monkeypatch):
    """Table 2's and Table 5's runs go group_size at a time through one train_runs call each."""
    from sdm.experiments import runs as experiments

    calls = []
    original = experiments.train_runs

    def counting(train_set, targets, settings, **kwargs):
        calls.append((len(targets), settings[0].fit_depth))
        return original(train_set, targets, settings, **kwargs)

    monkeypatch.setattr(experiments, "train_runs", counting)
    train_set, _ = sky768
    small = train_set.subset(range(32))
    settings = TrainSettings(lr=1e-4, n_epoch=1, s=2, seed=3)
    experiments.noise_runs(small, 1, range(5), settings, group_size=2)
    experiments.depth_noise_runs(small, 0.5, 1, range(5), settings, group_size=3)
    assert calls == [(2, False), (2, False), (1, False), (3, True), (2, True)]
    with pytest.raises(SDMInputError, match="group_size"):
        experiments.noise_runs(small, 1, [0], settings, group_size=0)
    with pytest.raises(SDMInputError, match="group_size"):
        experiments.depth_noise_runs(small, 0.5, 1, [0], settings, group_size=1.5)


def test_bad_runs_input(sky768):
    from sdm.train import train_runs

    train_set, _ = sky768
    small = train_set.subset(range(16))
    with pytest.raises(SDMInputError, match="differ only in seed"):
        train_runs(small, [small.targets] * 2, [TrainSettings(lr=1e-4), TrainSettings(lr=3e-4)])
    with pytest.raises(SDMInputError, match="one target set per run"):
        train_runs(small, [small.targets], [TrainSettings(), TrainSettings(seed=1)])
    with pytest.raises(SDMInputError, match=r"targets\[0\] must be bool"):
        train_runs(small, [small.targets.float()], [TrainSettings()])

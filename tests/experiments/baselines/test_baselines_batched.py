"""Many baseline runs as one program (``fit_runs``) against one ``fit`` per run.

Run ``r`` of ``fit_runs(sets, settings, seeds)`` must be ``fit(sets[r], settings, seed=seeds[r])``:
the same mini-batches and subsamples (drawn from its own generator in the same order), its own
Adam, its own theta. Tolerance: measured 0.0 m (bit-identical thetas at every step) for all three
methods on these sets, because each run's arithmetic is the single run's, element for element
(see :func:`sdm.experiments.baselines.common.subsample_runs` and :class:`~sdm.experiments.baselines.common.RowAdam`); the
tests allow 1e-12 m (a thousandth of the 1e-9 m asked; 1e-11 pixel at 20 m) so that a platform
whose reductions group a padded row differently does not fail them, while a bug that mixes runs
is far above it: every run drawing from run 0's generator moved run 1's theta by 3.1e-2 m on these
sets (``test_the_tolerance_catches_a_shared_generator``).
"""

from dataclasses import replace

import pandas as pd
import pytest
import torch

import baseline_reference
from run_reference import baseline_noise_run
from scenes import configuration_set
from sdm.experiments.baselines import (METHODS, RUN_COLUMNS, ChamferSettings, SilhouetteSettings, SinkhornSettings,
                           baseline_noise_runs)
from sdm.experiments.baselines import chamfer, common, silhouette, sinkhorn
from sdm.errors import SDMInputError
from sdm.experiments import noisy_targets

TOLERANCE_M = 1e-12

#: Short schedules (the defaults' structure: several stages, mini-batches of 16, subsampling on).
SHORT = {
    "silhouette": (silhouette, SilhouetteSettings(steps=6, s=2)),
    "chamfer": (chamfer, ChamferSettings(steps=8, rounds=3, max_points=48)),
    "sinkhorn": (sinkhorn, SinkhornSettings(steps=5, rounds=3, max_points=32)),
}


@pytest.fixture(scope="module")
def runs():
    """Three runs on 48 configurations: different noisy targets (levels 1, 3, 2) and seeds."""
    data = configuration_set(48, seed=23)
    draws = [(1, 101), (3, 202), (2, 303)]
    return [data.with_targets(noisy_targets(data.targets, noise_level, seed)) for noise_level, seed in draws], [s for _, s in draws]


def largest_difference(one, other) -> float:
    """Largest |difference| of two FitResults' thetas over every step of their histories, metres."""
    assert len(one.history["a"]) == len(other.history["a"])
    pairs = zip(one.history["a"] + one.history["b"], other.history["a"] + other.history["b"])
    return max(abs(x - y) for x, y in pairs)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SHORT))
def test_each_batched_run_is_its_single_run(runs, name, monkeypatch):
    if name == "sinkhorn":
        pytest.importorskip("geomloss")
        monkeypatch.setattr(sinkhorn, "OT_PROBLEMS_PER_SOLVE", 20)  # solves that cut runs' batches apart
    monkeypatch.setattr(chamfer, "CONFIGS_PER_SEARCH", 20)
    module, settings = SHORT[name]
    sets, seeds = runs
    batched = module.fit_runs(sets, settings, seeds)
    assert len(batched) == 3
    thetas = set()
    for data, seed, result in zip(sets, seeds, batched):
        single = module.fit(data, settings, seed=seed)
        assert result.evaluations == single.evaluations
        assert largest_difference(single, result) <= TOLERANCE_M, (name, seed)
        assert result.history["stage"] == single.history["stage"]
        assert result.history["loss"] == pytest.approx(single.history["loss"], rel=1e-6)
        thetas.add(result.theta)
    assert len(thetas) == 3  # the runs really differ: the comparison is not between copies
    assert batched[0].seconds == batched[1].seconds > 0  # the batch's wall time over R


def test_a_run_alone_is_the_same_whatever_runs_it_is_batched_with(runs):
    """Run 0 batched with the others, and run 0 batched with itself twice, agree with each other."""
    sets, seeds = runs
    _, settings = SHORT["chamfer"]
    together = chamfer.fit_runs(sets, settings, seeds)[0]
    doubled = chamfer.fit_runs([sets[0], sets[0]], settings, [seeds[0], seeds[0]])
    assert largest_difference(together, doubled[0]) <= TOLERANCE_M
    assert largest_difference(doubled[0], doubled[1]) == 0.0


def test_the_tolerance_catches_a_shared_generator(runs, monkeypatch):
    """A plausible bug (every run drawing from run 0's generator) breaks the equality by far more than the tolerance."""
    sets, seeds = runs
    _, settings = SHORT["chamfer"]
    single = chamfer.fit(sets[1], settings, seed=seeds[1])
    original = common.subsample_runs

    def shared(mask, widths, k, generators):
        return original(mask, widths, k, [generators[0]] * len(generators))

    monkeypatch.setattr(common, "subsample_runs", shared)  # sampled_pairs looks it up in common
    broken = chamfer.fit_runs(sets, settings, seeds)[1]
    assert largest_difference(single, broken) > 1e3 * TOLERANCE_M


@pytest.mark.slow
def test_row_adam_is_torch_adam_per_row_and_skips_per_row():
    """RowAdam on (3, 2) equals torch.optim.Adam on each row alone, to the bit; a row with a
    non-finite gradient keeps its theta and its Adam state (as one run alone would skip it)."""
    generator = torch.Generator().manual_seed(0)
    grads = torch.randn(7, 3, 2, generator=generator, dtype=torch.float64)
    grads[2, 1, 0] = float("nan")  # row 1 skips step 2
    grads[4, 2, 1] = float("inf")  # row 2 skips step 4
    theta = torch.zeros(3, 2, dtype=torch.float64, requires_grad=True)
    adam = common.RowAdam(theta)
    for step, grad in enumerate(grads):
        theta.grad = grad.clone()
        adam.step(0.1 * (step + 1), torch.isfinite(grad).all(1).tolist())
    for row in range(3):
        alone = torch.zeros(2, dtype=torch.float64, requires_grad=True)
        optimizer = torch.optim.Adam([alone], lr=0.1)
        for step, grad in enumerate(grads[:, row]):
            if bool(torch.isfinite(grad).all()):
                optimizer.param_groups[0]["lr"] = 0.1 * (step + 1)
                alone.grad = grad.clone()
                optimizer.step()
        assert torch.equal(theta.detach()[row], alone.detach()), row


def test_subsample_runs_draws_what_subsample_draws():
    """Each run's picks equal subsample() on its own mask and generator, widths above and below k."""
    widths, k = [9, 4, 12], 5
    mask = torch.zeros(3, 2, 12, dtype=torch.bool)
    for run, width in enumerate(widths):
        mask[run, :, : width - run] = True  # some rows shorter than their width
    index, kept = common.subsample_runs(mask, widths, k, [torch.Generator().manual_seed(s) for s in (1, 2, 3)])
    for run, width in enumerate(widths):
        generator = torch.Generator().manual_seed(run + 1)
        alone_index, alone_kept = baseline_reference.subsample(mask[run, :, :width], k, generator)
        n = alone_index.shape[1]
        assert torch.equal(kept[run, :, :n], alone_kept) and not kept[run, :, n:].any()
        assert torch.equal(index[run, :, :n][alone_kept], alone_index[alone_kept])


def test_noise_runs_batched_equal_the_loop(runs):
    """baseline_noise_runs through fit_runs (groups of 2 over 3 runs) gives the rows of each run fitted alone."""
    sets, _ = runs
    data = configuration_set(48, seed=23)
    _, settings = SHORT["chamfer"]
    assert METHODS["chamfer"].fit_runs is chamfer.fit_runs
    frame = baseline_noise_runs("chamfer", data, 2, [0, 3, 1], settings, seed=4, group_size=2)
    loop = pd.DataFrame([baseline_noise_run("chamfer", data, 2, run, settings, seed=4) for run in (0, 3, 1)])
    assert list(frame.columns) == RUN_COLUMNS and list(frame["run"]) == [0, 3, 1]
    assert list(frame["seed"]) == list(loop["seed"])
    assert (frame[["a", "b"]] - loop[["a", "b"]]).abs().to_numpy().max() <= TOLERANCE_M
    assert frame.loc[0, "seconds"] == frame.loc[1, "seconds"] > 0  # the first group's time over its runs
    with pytest.raises(SDMInputError, match="group_size"):
        baseline_noise_runs("chamfer", data, 2, [0], settings, seed=4, group_size=0)
    with pytest.raises(SDMInputError, match="settings for 'chamfer'"):
        baseline_noise_runs("chamfer", data, 2, [0], SilhouetteSettings(), seed=4)


def test_noise_runs_of_a_method_without_fit_runs_fit_each_run_alone(monkeypatch):
    """A method with no fit_runs gets one fit per run, on the same paired draws."""
    data = configuration_set(48, seed=23)
    _, settings = SHORT["chamfer"]
    monkeypatch.setitem(METHODS, "chamfer", replace(METHODS["chamfer"], fit_runs=None))
    frame = baseline_noise_runs("chamfer", data, 1, [2, 0], settings, seed=4)
    for row in frame.to_dict("records"):
        alone = baseline_noise_run("chamfer", data, 1, row["run"], settings, seed=4)
        assert (row["seed"], row["a"], row["b"]) == (alone["seed"], alone["a"], alone["b"])


def test_sdm_batched_equals_its_single_runs(monkeypatch):
    """sdm_layer.fit_runs is one train_runs call over its runs (the grouping is baseline_noise_runs'), run for run
    fit()."""
    from sdm.experiments import runs as experiments
    from sdm.experiments.baselines import sdm_layer
    from sdm.train import TrainSettings

    calls = []
    original = experiments.train_runs

    def counting(train_set, targets, settings, **kwargs):
        calls.append(len(targets))
        return original(train_set, targets, settings, **kwargs)

    monkeypatch.setattr(experiments, "train_runs", counting)
    data = configuration_set(48, seed=23)
    seeds = (5, 6, 7, 8, 9)
    sets = [data.with_targets(noisy_targets(data.targets, 2, seed)) for seed in seeds]
    settings = TrainSettings(lr=1e-3, n_epoch=1, s=2)
    batched = sdm_layer.fit_runs(sets, settings, list(seeds))
    assert calls == [5]
    assert len({result.theta for result in batched}) == 5
    for data_run, seed, result in zip(sets, seeds, batched):
        alone = sdm_layer.fit(data_run, settings, seed)
        assert result.theta == alone.theta and result.history["loss"] == alone.history["loss"]
    # Another start goes through the same one call, not one fit per run.
    calls.clear()
    start = (0.3, -0.2)
    moved = sdm_layer.fit_runs(sets[:2], settings, list(seeds[:2]), theta0=start)
    assert calls == [2]
    for data_run, seed, result in zip(sets, seeds, moved):
        alone = sdm_layer.fit(data_run, settings, seed, theta0=start)
        assert result.theta == alone.theta and result.history["loss"] == alone.history["loss"]
    calls.clear()
    frame = baseline_noise_runs("sdm", data, 2, range(5), settings, seed=1)  # the method's default group: Table 2's
    assert calls == [4, 1] and list(frame["run"]) == [0, 1, 2, 3, 4]


def test_runs_must_share_points_and_have_a_seed_each(runs):
    sets, seeds = runs
    other = configuration_set(48, seed=24)
    with pytest.raises(SDMInputError, match=r"train_sets\[1\]"):
        chamfer.fit_runs([sets[0], other], ChamferSettings(steps=1, rounds=1), [1, 2])
    with pytest.raises(SDMInputError, match="seeds"):
        chamfer.fit_runs(sets, ChamferSettings(steps=1, rounds=1), [1, 2])


def test_sampled_pairs_are_each_runs_sampled_pair(runs):
    """The batched draw gives run r what sampled_pair gives it alone (same generator seed), with
    subsampling on for points and for targets (max_points below every width) and off (0)."""
    sets, seeds = runs
    camera = sets[0].camera
    points, point_mask = common.pad_points(sets[0])
    targets = common.pack_run_targets([data.targets for data in sets])
    configs = torch.tensor([[0, 5, 9], [3, 5, 47], [12, 1, 2]])
    theta = torch.tensor([[0.5, 0.3], [0.1, -0.2], [0.0, 0.0]], dtype=torch.float64)
    for max_points in (7, 0):
        batched = common.sampled_pairs(points, point_mask, targets, configs, theta, camera, max_points,
                                       [torch.Generator().manual_seed(s) for s in seeds])
        for run, (data, seed) in enumerate(zip(sets, seeds)):
            alone = baseline_reference.sampled_pair(baseline_reference.pad_set(data), configs[run], theta[run], camera,
                                                    max_points, torch.Generator().manual_seed(seed))
            screen, kept, centres, target_kept = (t[run] for t in batched)
            n, m = alone[0].shape[1], alone[2].shape[1]
            assert torch.equal(kept[:, :n], alone[1]) and not kept[:, n:].any()
            assert torch.equal(screen[:, :n][alone[1]], alone[0][alone[1]])
            assert torch.equal(target_kept[:, :m], alone[3]) and not target_kept[:, m:].any()
            assert torch.equal(centres[:, :m][alone[3]], alone[2][alone[3]])

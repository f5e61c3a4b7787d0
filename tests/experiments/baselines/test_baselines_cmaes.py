"""The fast pixel-mismatch count of the CMA-ES baseline (sdm.experiments.baselines.mismatch) and its batched runs.

The fast count moves groups of points rigidly (same configuration, depth and sub-pixel offset)
and must give exactly the straightforward count: every point projected, floored, the rendered
image compared with the target, pixel by pixel. These tests hold it to that on random, far and
border thetas, with noise-free and noisy targets, on both of its paths (the compiled count of
``sdm.experiments.baselines.cmaes_native`` and the torch count it falls back to), and hold :func:`fit_runs` to :func:`fit`.
"""
import contextlib
import math

import numpy as np
import pytest
import torch

from scenes import configuration_set
from sdm import SKY_SHIFT
from sdm.experiments.baselines import cmaes, mismatch
from sdm.experiments.baselines.cmaes import CMAESSettings, fit, fit_runs
from sdm.experiments.baselines.mismatch import PixelMismatch, ShiftLayout
from sdm.errors import SDMInputError
from sdm.experiments import noisy_targets
from sdm.mapping import native
from sdm.sky import shifted_target

PATHS = ["compiled", "torch"]


@contextlib.contextmanager
def counting(path):
    """Objectives built inside count on ``path``: the compiled kernel (skipped without a C compiler) or torch."""
    if path == "compiled":
        if not native.enabled():
            pytest.skip("no C compiler: the compiled count is not built")
        yield
    else:
        with native.disabled():
            yield


@pytest.fixture(scope="module")
def small():
    """48 noise-free configurations (about 11 cars each)."""
    return configuration_set(48, seed=5)


def straightforward_count(train_set, theta) -> int:
    """False positives + false negatives: each configuration rendered at ``theta`` and compared with its target."""
    total = 0
    for index in range(len(train_set)):
        rows = slice(int(train_set.offsets[index]), int(train_set.offsets[index + 1]))
        rendered = shifted_target(train_set.points[rows], theta, train_set.camera)
        total += int((rendered ^ train_set.targets[index]).sum())
    return total


def random_thetas(count: int, seed: int, spread: float):
    rng = np.random.default_rng(seed)
    return [(float(a), float(b)) for a, b in rng.normal((0.5, 0.3), spread, size=(count, 2))]


@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("noise_level", [0, 3])
def test_fast_count_is_the_straightforward_count(small, noise_level, path):
    """Random thetas around and far from theta* (whole cars off screen: clamped groups), clean and noisy targets."""
    train_set = small.with_targets(noisy_targets(small.targets, noise_level, seed=17)) if noise_level else small
    with counting(path):
        objective = PixelMismatch(train_set)
    assert objective.native == (path == "compiled")
    thetas = random_thetas(12, seed=noise_level, spread=0.3) + random_thetas(6, seed=10 + noise_level, spread=3.0)
    thetas += [(0.0, 0.0), SKY_SHIFT, (40.0, -25.0)]
    expected = [straightforward_count(train_set, theta) for theta in thetas]
    assert [objective(theta) for theta in thetas] == expected
    assert objective.many(thetas) == expected  # all at once (one pass of the compiled count)
    assert objective.fallbacks == 0  # the fast path was taken every time, not the reference
    assert objective.evaluations == 2 * len(thetas)
    if noise_level == 0:
        assert objective(SKY_SHIFT) == 0


@pytest.mark.parametrize("path", PATHS)
def test_one_pixel_tiles_take_the_wide_table(small, monkeypatch, path):
    """Tiles of one pixel: a group per point, hundreds per configuration, so (torch) int32 entries with int16 codes."""
    monkeypatch.setattr(mismatch, "TILE", 1)
    with counting(path):
        objective = PixelMismatch(small)
    assert objective.table.dtype == (torch.int8 if objective.native else torch.int32)
    assert objective.layout.gain.shape[0] == small.points.shape[0]
    for theta in random_thetas(4, seed=21, spread=0.3) + [(6.0, -3.0)]:
        assert objective(theta) == straightforward_count(small, theta), theta
    assert objective.fallbacks == 0


def test_groups_move_several_points_and_overlaps_are_counted_once(small):
    """The grouping is what makes it fast, and groups do overlap after a shift (the de-duplication is exercised)."""
    layout = ShiftLayout(small)
    assert layout.usable
    assert layout.gain.shape[0] * 10 < small.points.shape[0]  # on average more than 10 points per group
    overlapped = 0
    for theta in random_thetas(8, seed=3, spread=0.3):
        ids = layout.rendered_ids(theta)
        on_screen = (PixelMismatch(small, layout=layout).table.gather(0, ids) & 255) != 1  # low half: weight + 1
        overlapped += int(on_screen.sum()) - int(torch.unique(ids[on_screen]).numel())
    assert overlapped > 0


@pytest.mark.parametrize("path", PATHS)
def test_border_theta_falls_back_to_the_reference(small, path):
    """A theta that puts a group's points exactly on a pixel border is counted by reference, and still right,
    also among trusted thetas in one call."""
    with counting(path):
        objective = PixelMismatch(small)
    layout = objective.layout
    # b such that frac(row_0) + b g_r of the last group is the next integer: its points sit on a row border.
    b = (1.0 - float(layout.frac_low[-1, 0])) / float(layout.gain[-1, 0])
    theta = (0.3, b)
    assert layout.rendered_ids(theta) is None
    assert objective(theta) == objective.reference(theta)
    assert objective.fallbacks == 1
    others = random_thetas(3, seed=2, spread=0.3)
    assert objective.many([others[0], theta, *others[1:]]) == [
        straightforward_count(small, t) for t in (others[0], theta, *others[1:])]
    assert objective.fallbacks == 2 and objective.evaluations == 5


def test_compiled_count_wipes_its_stamps_before_they_wrap(small):
    """The compiled count marks pixels with 32-bit stamps that it wipes before they run out: still exact after."""
    with counting("compiled"):
        objective = PixelMismatch(small)
    thetas = random_thetas(6, seed=31, spread=0.3)
    expected = [straightforward_count(small, theta) for theta in thetas]
    stamp = objective.layout.stamp
    stamp[-1] = -2 - len(small) * 2  # uint32 2**32 - 2 - 2 N: the next call of 6 needs a wipe, a call of 2 does not
    assert objective.many(thetas[:2]) == expected[:2]
    assert int(stamp[-1]) == -2  # stamps 2**32 - 2 N - 1 .. 2**32 - 2 used, none wrapped to 0
    assert objective.many(thetas) == expected
    assert 0 < int(stamp[-1]) <= len(small) * len(thetas)  # wiped, then counted up from 0


def test_compiled_count_reuses_configurations_that_shift_alike_and_stays_exact(small):
    """The compiled count remembers its last candidates (MismatchMemo): a configuration whose groups all shift as
    in one of them takes that sum. Candidates a millimetre apart (some groups of a configuration cross a pixel
    border, most do not), repeated ones, and a call larger than the memo, on noisy targets: every count is the
    straightforward one, and a second objective (other targets) never takes the first one's sums."""
    noisy = small.with_targets(noisy_targets(small.targets, 2, seed=8))
    with counting("compiled"):
        objective = PixelMismatch(noisy)
        other = PixelMismatch(small, layout=objective.layout)
    assert objective._memo.slots == mismatch.MismatchMemo.SLOTS
    near = random_thetas(18, seed=40, spread=1e-3)
    calls = [near[:6], near[3:9], [near[4], near[4], *near[9:13]], near[12:18]]
    for thetas in calls:
        assert objective.many(thetas) == [straightforward_count(noisy, theta) for theta in thetas]
    assert other.many(near[:6]) == [straightforward_count(small, theta) for theta in near[:6]]
    wide = near[:13]  # more candidates than slots: the memo grows, emptied, and counts stay exact
    assert objective.many(wide) == [straightforward_count(noisy, theta) for theta in wide]
    assert objective._memo.slots == 13
    assert objective.many(near[:6]) == [straightforward_count(noisy, theta) for theta in near[:6]]


def test_compiled_and_torch_counts_agree_on_a_search(small):
    """The whole search on either path: the same candidates, counts and result (Table 3's cmaes rows)."""
    pytest.importorskip("cma")
    noisy = small.with_targets(noisy_targets(small.targets, 2, seed=6))
    results = {}
    for path in PATHS:
        with counting(path):
            results[path] = fit(noisy, CMAESSettings(budget=60), seed=4)
    assert results["compiled"].theta == results["torch"].theta
    assert results["compiled"].history == results["torch"].history
    assert results["compiled"].evaluations == results["torch"].evaluations


def test_reference_is_the_straightforward_count(small):
    noisy = small.with_targets(noisy_targets(small.targets, 2, seed=4))
    objective = PixelMismatch(noisy)
    for theta in random_thetas(5, seed=9, spread=0.5):
        assert objective.reference(theta) == straightforward_count(noisy, theta), theta


class ReferenceOnly(PixelMismatch):
    """Every evaluation by the reference count (the objective as it was before the fast count)."""

    def many(self, thetas) -> list[int]:
        self.evaluations += len(thetas)
        return [self.reference(theta) for theta in thetas]


@pytest.mark.parametrize("path", PATHS)
def test_fit_is_the_search_on_the_reference_count(small, path):
    """Same candidates, same counts, same ranking: the fast count changes no CMA-ES decision."""
    pytest.importorskip("cma")
    noisy = small.with_targets(noisy_targets(small.targets, 1, seed=8))
    settings = CMAESSettings(budget=60)
    with counting(path):
        fast = fit(noisy, settings, seed=3)
    slow = cmaes.cmaes_search(ReferenceOnly(noisy), settings, 3, (0.0, 0.0))
    assert fast.theta == slow.theta
    assert fast.history == slow.history
    assert fast.evaluations == slow.evaluations > 60


def test_fit_runs_is_fit_run_by_run(small):
    """Three runs with their own noisy targets and seeds: each equals its own fit (theta, history, evaluations)."""
    pytest.importorskip("cma")
    seeds = [11, 12, 13]
    sets = [small.with_targets(noisy_targets(small.targets, 3, seed)) for seed in seeds]
    settings = CMAESSettings(sigma0=0.3, budget=48)
    together = fit_runs(sets, settings, seeds)
    assert len(together) == 3
    thetas = set()
    for train_set, seed, result in zip(sets, seeds, together):
        alone = fit(train_set, settings, seed=seed)
        assert result.theta == alone.theta
        assert result.history == alone.history
        assert result.evaluations == alone.evaluations
        thetas.add(result.theta)
    assert len(thetas) == 3  # the runs really differ (targets and seeds reach the search)
    assert together[0].seconds > 0 and len({result.seconds for result in together}) == 1  # wall time / R


def test_fit_runs_with_other_points_builds_their_own_layout(small):
    """Sets with different points in one call (not the intended use) still give each run its own fit."""
    pytest.importorskip("cma")
    sets = [small, small.subset(range(24)), small.with_targets(noisy_targets(small.targets, 1, 2))]
    settings, seeds = CMAESSettings(budget=24), [1, 2, 3]
    for train_set, seed, result in zip(sets, seeds, fit_runs(sets, settings, seeds)):
        assert result.theta == fit(train_set, settings, seed=seed).theta


def test_fit_runs_checks_its_arguments(small):
    with pytest.raises(SDMInputError, match="seeds"):
        fit_runs([small, small], CMAESSettings(), [1])
    assert fit_runs([], CMAESSettings(), []) == []


PYCMA_PROBE = """
import sys, warnings
warnings.simplefilter("error")
if sys.argv[1] == "preloaded":
    import matplotlib, scipy.stats  # a process that has them: pycma sees them as a plain import would
from scenes import configuration_set
from sdm.experiments.baselines.cmaes import CMAESSettings, cmaes_search
from sdm.experiments.baselines.mismatch import PixelMismatch
from sdm.experiments.baselines.pycma import import_cma
cma = import_cma()
hidden = [name for name in ("scipy.stats", "matplotlib") if name not in sys.modules]
import matplotlib, scipy.stats  # importable again afterwards
data = configuration_set(24, seed=3)
result = cmaes_search(PixelMismatch(data), CMAESSettings(budget=60), 5, (0.0, 0.0))
print(repr((hidden, result.theta, result.evaluations, result.history)))
"""


@pytest.mark.slow
def test_cma_is_imported_without_its_plots_and_surrogates_and_searches_the_same():
    """import_cma() imports cma without scipy.stats and matplotlib (most of its import time), silently, leaves both
    importable, and a search gives the same theta, history and count as in a process that imported them first."""
    pytest.importorskip("cma")
    import subprocess
    import sys
    from pathlib import Path

    tests = Path(__file__).parents[2]
    env = {**__import__("os").environ, "PYTHONPATH": f"{tests}:{tests.parent / 'src'}"}

    def probe(mode):
        out = subprocess.run([sys.executable, "-c", PYCMA_PROBE, mode], capture_output=True, text=True, env=env,
                             timeout=300)
        assert out.returncode == 0, out.stderr
        return eval(out.stdout.strip().splitlines()[-1], {"__builtins__": {}}, {})

    alone, preloaded = probe("alone"), probe("preloaded")
    assert alone[0] == ["scipy.stats", "matplotlib"] and preloaded[0] == []
    assert alone[1:] == preloaded[1:]

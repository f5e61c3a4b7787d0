"""The floor (sdm.experiments.baselines.floor): the exact-mismatch minimiser of a run and its minimal region.

Held to the straightforward count (:meth:`PixelMismatch.reference`) and to a brute-force count of
every cell of the step function in a window (tests/floor_reference.py), on tiny seeded scenes.
"""
from dataclasses import replace

import pytest

from floor_reference import cell_minimum, grid_minimum
from scenes import configuration_set
from sdm import SKY_SHIFT
from sdm.experiments.baselines.mismatch import PixelMismatch
from sdm.experiments.baselines.floor import FLOOR_COLUMNS, FloorSettings, floor_runs, floor_search
from sdm.errors import SDMInputError
from sdm.experiments import noisy_targets, run_seed

#: A smaller budget per CMA-ES run: the tiny scenes' runs stop on their own well within it.
SMALL = FloorSettings(budget=600)


@pytest.fixture(scope="module")
def tiny():
    """4 noise-free configurations (about 2,500 points)."""
    return configuration_set(4, seed=2)


def noisy(train_set, noise_level, draw):
    return train_set.with_targets(noisy_targets(train_set.targets, noise_level, seed=draw)) if noise_level else train_set


def test_noise_free_floor_holds_the_truth(tiny):
    result = floor_search(PixelMismatch(tiny), seed=0, settings=SMALL)
    assert result.min_mismatch == 0 and result.mismatch_at_truth == 0  # theta* is in the minimal region
    assert PixelMismatch(tiny).reference(result.theta) == 0
    # theta* lies within the region's extent around its centre (a region far narrower would not hold it)
    for axis in (0, 1):
        assert abs(result.theta[axis] - SKY_SHIFT[axis]) <= result.extent[axis] / 2
    assert result.distance < 0.01 and result.extent[0] > 0 and result.extent[1] > 0


@pytest.mark.parametrize("noise_level, draw", [(2, 7), (4, 3)])
def test_minimum_is_the_reference_count(tiny, noise_level, draw):
    train_set = noisy(tiny, noise_level, draw)
    result = floor_search(PixelMismatch(train_set), seed=1, settings=SMALL)
    reference = PixelMismatch(train_set).reference
    assert reference(result.theta) == result.min_mismatch
    assert reference(result.search_theta) == result.min_mismatch
    assert reference(result.half.theta) == result.half.mismatch
    assert reference(SKY_SHIFT) == result.mismatch_at_truth >= result.min_mismatch


@pytest.mark.parametrize("noise_level, draw", [(0, 0), (2, 7), (4, 3)])
def test_extent_is_tight(tiny, noise_level, draw):
    """Along each measured line: the minimum everywhere inside the interval, more just past either end."""
    train_set = noisy(tiny, noise_level, draw)
    result = floor_search(PixelMismatch(train_set), seed=2, settings=SMALL)
    region, reference, eps = result.region, PixelMismatch(train_set).reference, 2 * SMALL.extent_tol
    lines = [(region.interval_a, lambda a: (a, region.search_theta[1])),
             (region.interval_b, lambda b: (region.theta[0], b))]
    for (low, high), at in lines:
        assert high - low > 2 * eps
        inside = [low + (high - low) * k / 8 for k in range(9)]
        assert [reference(at(v)) for v in inside] == [result.min_mismatch] * 9
        assert reference(at(low - eps)) > result.min_mismatch
        assert reference(at(high + eps)) > result.min_mismatch
    assert result.extent == (region.interval_a[1] - region.interval_a[0], region.interval_b[1] - region.interval_b[0])
    assert region.interval_a[0] < region.theta[0] < region.interval_a[1]


@pytest.mark.parametrize("noise_level, draw", [(0, 0), (1, 4), (2, 7), (2, 8)])
def test_no_cell_counts_lower(tiny, noise_level, draw):
    """Every cell of the step function within 0.1 m of theta* and a 3 mm grid over +-0.3 m: none lower."""
    train_set = noisy(tiny, noise_level, draw)
    objective = PixelMismatch(train_set)
    result = floor_search(objective, seed=3, settings=SMALL)
    exact, _ = cell_minimum(objective, SKY_SHIFT, 0.1)
    assert result.min_mismatch == exact
    coarse, _ = grid_minimum(objective, SKY_SHIFT, 0.3, 0.003)
    assert coarse >= result.min_mismatch


def test_half_is_the_search_with_half_the_restarts(tiny):
    train_set = noisy(tiny, 4, 3)
    full = floor_search(PixelMismatch(train_set), seed=4, settings=SMALL)
    half = floor_search(PixelMismatch(train_set), seed=4, settings=replace(SMALL, restarts=2))
    assert full.half == half.region
    assert full.restart_best[:2] == half.restart_best
    assert full.min_mismatch <= full.half.mismatch


def test_same_seed_same_floor(tiny):
    train_set = noisy(tiny, 2, 7)
    first = floor_search(PixelMismatch(train_set), seed=5, settings=SMALL)
    second = floor_search(PixelMismatch(train_set), seed=5, settings=SMALL)
    assert (first.region, first.half, first.evaluations, first.restart_best) == \
        (second.region, second.half, second.evaluations, second.restart_best)


def test_a_poor_start_is_searched_from_wherever_a_probe_counts_lower(tiny):
    """One generation of CMA-ES and no compass search: the region's probes walk on to lower counts,
    and the floor still ends where the count is minimal along its lines."""
    train_set = noisy(tiny, 2, 7)
    weak = FloorSettings(restarts=2, budget=1, sigma0=1e-3, refine_step=1e-6, refine_tol=1e-6)
    objective = PixelMismatch(train_set)
    result = floor_search(objective, seed=0, settings=weak, theta0=(0.5, 0.28))
    start = PixelMismatch(train_set)(result.restart_best[-1][1])
    assert result.min_mismatch < start  # the probes moved it on
    reference, region, eps = PixelMismatch(train_set).reference, result.region, 2e-6
    assert reference(result.theta) == result.min_mismatch
    for (low, high), at in [(region.interval_a, lambda a: (a, region.search_theta[1])),
                            (region.interval_b, lambda b: (region.theta[0], b))]:
        inside = [low + (high - low) * k / 8 for k in range(9)]
        assert [reference(at(v)) for v in inside] == [result.min_mismatch] * 9
        assert reference(at(low - eps)) > result.min_mismatch < reference(at(high + eps))


def test_theta_star_is_a_candidate_of_both_budgets(tiny):
    """A search too weak to leave its start far from theta* (one generation, from (0, 0)) still ends no higher
    than theta*'s count, in the full and the half-budget floor: theta* is one more candidate of each."""
    train_set = noisy(tiny, 3, 5)
    weak = FloorSettings(restarts=2, budget=1, sigma0=1e-4, refine_step=1e-6, refine_tol=1e-6)
    result = floor_search(PixelMismatch(train_set), seed=0, settings=weak, theta0=(0.0, 0.0))
    assert PixelMismatch(train_set)((0.0, 0.0)) > result.mismatch_at_truth  # the start is far worse
    assert result.min_mismatch <= result.mismatch_at_truth
    assert result.half.mismatch <= result.mismatch_at_truth
    assert result.restart_best[-1][0] > result.mismatch_at_truth  # CMA-ES itself stayed above it


@pytest.mark.parametrize("field, value", [
    ("restarts", 3), ("restarts", 0), ("budget", 0), ("budget", 2.5), ("sigma0", -0.1), ("sigma_decay", 1.5),
    ("sigma_decay", 0.0), ("popsize", -1), ("tolx", 0.0), ("refine_step", float("nan")), ("refine_tol", 0.1),
    ("extent_tol", 2.0), ("extent_reach", 0.0),
])
def test_bad_settings_name_the_field(field, value):
    with pytest.raises(SDMInputError, match=f"FloorSettings.{field} ") as error:
        FloorSettings(**{field: value})
    assert error.value.field == field


def test_floor_runs_are_the_paired_runs(tiny):
    rows = floor_runs(tiny, 2, [0, 3], seed=9, settings=SMALL)
    assert list(rows.columns) == FLOOR_COLUMNS and rows["run"].tolist() == [0, 3]
    for _, row in rows.iterrows():
        seed = run_seed(9, 2, int(row["run"]))
        assert row["seed"] == seed
        alone = floor_search(PixelMismatch(noisy(tiny, 2, seed)), seed, SMALL)
        assert (row["a"], row["b"]) == alone.theta and row["distance"] == alone.distance
        assert (row["search_a"], row["search_b"], row["search_distance"]) == (*alone.search_theta,
                                                                             alone.search_distance)
        assert (row["extent_a"], row["extent_b"]) == alone.extent
        assert (row["min_mismatch"], row["mismatch_at_truth"]) == (alone.min_mismatch, alone.mismatch_at_truth)
        assert row["half_distance"] == alone.half_distance and row["evaluations"] == alone.evaluations
        assert row["seconds"] > 0
    # The clean targets may come apart from the set (e.g. a set whose own targets are already noisy).
    other = floor_runs(noisy(tiny, 3, 1), 2, [0, 3], seed=9, settings=SMALL, clean_targets=tiny.targets)
    assert other.drop(columns="seconds").equals(rows.drop(columns="seconds"))


def test_floor_runs_bad_input(tiny):
    with pytest.raises(SDMInputError, match="clean_targets"):
        floor_runs(tiny, 1, [0], seed=0, settings=SMALL, clean_targets=tiny.targets[:2])
    with pytest.raises(SDMInputError, match="FloorSettings"):
        floor_runs(tiny, 1, [0], seed=0, settings=SMALL.cmaes(0))

"""Table 6's driver (sdm.experiments.objects) and its report (sdm.experiments.report.objects) on a few configurations."""
from __future__ import annotations

from dataclasses import replace

import pandas as pd
import pytest
import torch

from sdm.experiments.baselines.rows import RowsCMAESSettings, RowsFloorSettings
from sdm.experiments.baselines.silhouette import SilhouetteSettings
from sdm.errors import SDMInputError
from sdm.experiments.objects import EXACT_SET, METHODS, REFERENCES, ObjectsSettings, objects_runs, scaling_runs
from sdm.experiments.report.objects import read_units_archive, table6, table6_summary, tail_words, units_archive, verdict_facts
from sdm.experiments.report.scaling import scaling_table, scaling_words
from sdm.train import TrainSettings

from sdm.batch import ConfigurationSet

from scenes import configurations

SETTINGS = ObjectsSettings(
    warm=TrainSettings(lr=1e-3, n_epoch=2, s=3), rows=TrainSettings(lr=5e-3, n_epoch=1, s=2),
    schedule="closed_centred_r1+group_crossing:1", cmaes=RowsCMAESSettings(evaluations_per_unknown=10),
    floor=RowsFloorSettings(evaluations_per_unknown=10), silhouette=SilhouetteSettings(steps=3, batch_size=8))


@pytest.fixture(scope="module")
def data():
    return ConfigurationSet.from_configurations(configurations(16, seed=41, mean_cars=3))


@pytest.mark.slow
def test_every_method_scores_the_same_units_of_a_run(data):
    runs = objects_runs(data, "car", 2, [0], seed=3, settings=SETTINGS)
    scored = runs[runs["method"] != "hidden"]
    assert set(scored["method"]) == set(METHODS) | set(REFERENCES)
    per_method = scored.groupby("method")
    assert per_method["unit"].apply(sorted).apply(tuple).nunique() == 1  # the same units for every method
    assert per_method[["a_true", "b_true"]].apply(lambda f: tuple(f.to_numpy().ravel())).nunique() == 1
    assert (scored["distance"] >= 0).all() and (scored.loc[scored["method"] != "prior", "cpu_s"] > 0).all()
    again = objects_runs(data, "car", 2, [0], seed=3, settings=SETTINGS)
    pd.testing.assert_frame_equal(runs.drop(columns="cpu_s"), again.drop(columns="cpu_s"))  # seeded


def test_do_nothing_references_are_paired_with_each_method(data):
    runs = objects_runs(data, "camera+car", 0, [0], seed=3, settings=SETTINGS, methods=["sdm_schedule", "cmaes"])
    by = {method: frame.set_index("unit") for method, frame in runs.groupby("method")}
    start, prior = by["start"], by["prior"]
    assert (start["distance"] == start["start"]).all()  # the shared start is its own start
    centre = torch.tensor(SETTINGS.truth.centre, dtype=torch.float64)
    truth = torch.tensor(prior[["a_true", "b_true"]].to_numpy())
    assert torch.allclose(torch.tensor(prior["distance"].to_numpy()), (truth - centre).norm(dim=1))
    assert (prior[["a", "b"]].to_numpy() == list(SETTINGS.truth.centre)).all()
    assert (by["cmaes"]["start"] == start["distance"]).all()  # CMA-ES is given the paper's shared start
    # the schedule is given its own rule's shared start: a camera row at it, every residual at zero
    table = table6([runs])
    row = table[table["method"] == "cmaes"].iloc[0]
    assert row["of_start"] == pytest.approx(by["cmaes"]["distance"].mean() / start["distance"].mean())
    assert row["closer"] == pytest.approx((by["cmaes"]["distance"] < start["distance"]).mean())
    assert table[table["method"] == "start"].iloc[0]["of_start"] == pytest.approx(1.0)


def test_sdm_moves_every_configuration_towards_its_own_shift(data):
    strong = replace(SETTINGS, warm=replace(SETTINGS.warm, n_epoch=8), rows=replace(SETTINGS.rows, n_epoch=4))
    runs = objects_runs(data, "configuration", 0, [0], seed=4, settings=strong, methods=["sdm_paper"])
    scored = runs[runs["method"] == "sdm_paper"]
    start = (scored[["a_true", "b_true"]].to_numpy() ** 2).sum(1) ** 0.5  # from (0, 0)
    assert scored["distance"].median() < 0.5 * float(torch.tensor(start).median())


@pytest.mark.slow
def test_table6_and_its_words(data):
    frames = [objects_runs(data, noise_level, noise, [0], seed=5, settings=SETTINGS)
              for noise_level in ("configuration", "camera+car") for noise in (0, 1)]
    table = table6(frames, pd.DataFrame({"noise_level": [0, 0, 1], "run": [0, 1, 0], "distance": [1e-3, 3e-3, 2e-2]}))
    shared = table[table["sharing"] == "shared"].set_index("noise_level")
    assert shared.loc[0, "mean_m"] == pytest.approx(2e-3) and shared.loc[0, "units"] == 2
    rows = table[(table["sharing"] == "configuration") & (table["noise_level"] == 1)].set_index("method")
    assert list(rows.index) == list(REFERENCES) + list(METHODS)
    own = frames[1][frames[1]["method"] == "cmaes"]["distance"]
    assert rows.loc["cmaes", "mean_m"] == pytest.approx(own.mean())
    words = table6_summary(table)
    assert "A configuration's shift" in words and "of its start's error" in words
    found = verdict_facts(table)
    assert [(row["sharing"], row["noise_level"]) for row in found["rows"]] == [
        ("configuration", 0), ("configuration", 1), ("camera+car", 0), ("camera+car", 1)]
    row = found["rows"][1]
    by = rows  # the configuration level at noise 1
    sdm = min(("sdm_paper", "sdm_schedule"), key=lambda m: by.loc[m, "mean_m"] if m in by.index else float("inf"))
    assert row["rule"] == sdm and row["removed"] == pytest.approx(1 - by.loc[sdm, "of_start"])
    assert row["peer"] is not None and row["cpu_ratio"] == pytest.approx(
        by.loc[row["peer"], "cpu_ms"] / by.loc[sdm, "cpu_ms"])
    old = table.drop(columns=["scale", "start_m", "of_start", "closer", "extent_a_m", "extent_b_m"])  # an old snapshot
    assert verdict_facts(old)["rows"] == []  # no reference columns: nothing against doing nothing


def test_scaling_gives_one_point_per_budget(data):
    from sdm.experiments.data import set_with_cars

    cars = set_with_cars(16, 2, seed=0)
    frame = scaling_runs(cars, 2, 0, [0], seed=1, settings=SETTINGS, epochs=[1, 2], budgets=[5])
    assert sorted(zip(frame["method"], frame["budget"])) == [
        ("cmaes", 5), ("cmaes_car", 5), ("prior", 0), ("sdm_paper", 1), ("sdm_paper", 2), ("sdm_schedule", 1),
        ("sdm_schedule", 2), ("start", 0)]
    fitted = frame[~frame["method"].isin(["prior"])]
    assert (fitted["cpu_s"] > 0).all()
    start = frame[frame["method"] == "start"].iloc[0]
    paper_started = frame[frame["method"] != "sdm_schedule"]  # the schedule is scored against its own shared start
    assert (paper_started["start"] == start["mean"]).all() and start["closer"] == 0.0
    assert frame["gated_mean"].notna().all() and start["gated_mean"] == start["mean"]
    kept = scaling_runs(cars, 2, 0, [0], seed=1, settings=replace(SETTINGS, gate=1e6), epochs=[1], budgets=[5])
    assert (kept["gated_mean"] == kept["mean"]).all()  # no car travels 1e6 sd
    returned = scaling_runs(cars, 2, 0, [0], seed=1, settings=replace(SETTINGS, gate=1e-9), epochs=[1], budgets=[5])
    moved = returned[returned["mean"] != returned["start"]]  # a gate of 1e-9 sd returns every moved car
    assert len(moved) and (moved["gated_mean"] - moved["start"]).abs().max() < 1e-12
    assert (moved["gated_closer"] == 0.0).all()
    assert "doing nothing" in "\n".join(scaling_words(scaling_table([frame])))


def test_bad_sharing_and_method_are_named(data):
    with pytest.raises(SDMInputError, match="sharing must be one of"):
        objects_runs(data, "shared", 0, [0], seed=0, settings=SETTINGS)
    with pytest.raises(SDMInputError, match="methods must be of"):
        objects_runs(data, "car", 0, [0], seed=0, settings=SETTINGS, methods=["adam"])


def test_exact_sets_are_scored_on_the_first_run_and_read_beside_the_distances(data):
    runs = objects_runs(data, "car", 0, [0, 1], seed=6, settings=SETTINGS, methods=["sdm_paper"], scan=(0.3, 0.02))
    sets = runs[runs["method"] == EXACT_SET]
    assert set(sets["run"]) == {0}  # the first run only
    others = runs[(runs["method"] == "sdm_paper") & (runs["run"] == 0)]
    assert sorted(sets["unit"]) == sorted(others["unit"])  # every unit of the run
    assert (sets["extent_a"] > 0).all() and (sets["extent_b"] > 0).all()
    assert runs.loc[runs["method"] != EXACT_SET, "extent_a"].isna().all()
    table = table6([runs.assign(scale=2)])
    assert set(table["scale"]) == {2}
    row = table[table["method"] == "sdm_paper"].iloc[0]
    assert row["extent_a_m"] == pytest.approx(sets["extent_a"].median())
    assert row["extent_b_m"] == pytest.approx(sets["extent_b"].median())
    assert table[table["method"] == EXACT_SET].iloc[0]["mean_m"] == pytest.approx(sets["distance"].mean())
    assert "its pixels identify it to a median" in table6_summary(table)


def test_the_floor_is_theta_star_where_theta_star_reproduces_the_target(data):
    clean = objects_runs(data, "car", 0, [0], seed=7, settings=SETTINGS, methods=["floor"])
    floor = clean[clean["method"] == "floor"]
    assert (floor["distance"] == 0).all()
    assert (floor[["a", "b"]].to_numpy() == floor[["a_true", "b_true"]].to_numpy()).all()
    noisy = objects_runs(data, "car", 2, [0], seed=7, settings=SETTINGS, methods=["floor"])
    assert noisy.loc[noisy["method"] == "floor", "distance"].max() > 0  # under noise it searches


def test_two_screens_give_two_blocks_each_naming_its_scale(data):
    fine = objects_runs(data, "car", 0, [0], seed=8, settings=SETTINGS, methods=["sdm_paper", "cmaes_car"])
    table = table6([fine.assign(scale=4), fine.assign(scale=1)],
                   pd.DataFrame({"noise_level": [0], "run": [0], "distance": [1e-3]}))
    assert list(dict.fromkeys(table["scale"])) == [4, 1]  # the first screen first
    assert table.loc[table["sharing"] == "shared", "scale"].tolist() == [1]  # Table 2's runs: the Sky screen
    assert len(table[(table["scale"] == 4) & (table["method"] == "sdm_paper")]) == 1
    words = table6_summary(table)
    assert "scale 4 (512 x 1024)" in words and "scale 1 (128 x 256, the paper's)" in words
    assert words.index("scale 4") < words.index("scale 1 (")
    assert [row["scale"] for row in verdict_facts(table)["rows"]] == [4, 1]  # the first screen first


def test_the_units_archive_holds_every_record(data, tmp_path):
    runs = objects_runs(data, "configuration", 0, [0], seed=9, settings=SETTINGS, methods=["sdm_paper"])
    from sdm.experiments.data import set_with_cars

    scaled = scaling_runs(set_with_cars(16, 1, seed=0), 1, 0, [0], seed=1, settings=SETTINGS, epochs=[1], budgets=[5])
    archive = units_archive([runs.assign(scale=1)], [scaled.assign(scale=1)])
    assert archive == units_archive([runs.assign(scale=1)], [scaled.assign(scale=1)])  # no time stamp
    (tmp_path / "units.csv.gz").write_bytes(archive)
    back = read_units_archive(tmp_path / "units.csv.gz")
    assert len(back) == len(runs) + len(scaled)
    own = back[back["table"] == "runs"].reset_index(drop=True)
    assert own["distance"].to_numpy() == pytest.approx(runs["distance"].to_numpy(), rel=1e-6)
    assert (own["method"] == runs["method"]).all()


def test_scaling_reports_the_exact_sets_and_the_crossover():
    from sdm.experiments.data import set_with_cars

    cars = set_with_cars(16, 2, seed=0)
    frame = scaling_runs(cars, 2, 0, [0, 1], seed=1, settings=SETTINGS, epochs=[1], budgets=[5], scan=(0.3, 0.02))
    sets = frame[frame["method"] == EXACT_SET]
    assert len(sets) == 1 and sets.iloc[0]["run"] == 0 and sets.iloc[0]["extent_a"] > 0
    words = "\n".join(scaling_words(scaling_table([frame.assign(scale=3)])))
    assert "scale 3" in words and "exact-match set" in words
    assert "crossover" in words or "closer to theta* than" in words


@pytest.mark.parametrize("rows, expected", [
    ([(2, 2.0, 1.0, 3.0, "p", 50.0), (8, 1.5, 1.0, 3.0, "p", 40.0)], "No crossover: at every K measured (2-8)"),
    ([(2, 2.0, 1.0, 3.0, "p", 50.0), (8, 0.5, 1.0, 3.0, "p", 40.0)], "it overtakes the best peer from K = 8 on."),
    ([(2, 0.5, 1.0, 3.0, "p", 50.0), (8, 2.0, 1.0, 3.0, "p", 40.0)], "the best peer overtakes it from K = 8 on."),
    ([(2, 0.5, 1.0, 3.0, "p", 50.0), (8, 0.5, 4.0, 3.0, "p", 40.0)],
     "at every K measured (2-8). The best peer ends farther than doing nothing at K = 8."),
])
def test_the_crossover_in_words(rows, expected):
    from sdm.experiments.report.scaling import _crossover

    assert expected in _crossover(rows)


def test_tail_words_say_which_cars_make_the_mean():
    """Two runs of one configuration with three cars: the far runs' share of the summed distance and the worst car's,
    counted from the records; other methods, sharing levels and screens are left out. After the gate, the runs it
    returned (those whose gated distance is not their distance) and their share."""
    def records(scale, method="sdm_schedule", sharing="car"):
        distance = [0.5, 0.01, 0.02, 0.3, 0.01, 0.2]
        return pd.DataFrame({"scale": scale, "sharing": sharing, "noise_level": 0, "run": [0, 0, 0, 1, 1, 1],
                             "method": method, "config": 0, "car": [0, 1, 2, 0, 1, 2], "distance": distance,
                             "gated": [0.2, *distance[1:]]})  # run 0's car 0 returned to its start: 0.5 -> 0.2
    frames = [records(12), records(1, "cmaes"), records(12, "sdm_paper"), records(12, sharing="configuration"),
              records(1).assign(distance=9.0)]
    words = tail_words(frames, 12, worst=1)
    assert words == ["- Car level, noise 0, the recommended schedule, where the mean comes from: 2 runs of the same 1 "
                     "configurations (3 cars, each run with its own theta* and start); 50 % of the cars' runs end "
                     "farther than 0.1 m from theta* and make 96 % of the summed distance; the 1 cars with the largest "
                     "mean make 77 % of it, each ending that far in 100-100 % of its runs."]
    assert tail_words([], 12) == [] and tail_words(frames, 3) == []
    words = tail_words(frames, 12, worst=1, gated=True)
    assert words[0].startswith("- Car level, noise 0, the recommended schedule with the prior gate, where the mean")
    assert words[0].endswith("; the gate returned 16.7 % of the cars' runs to their start, 27 % of the summed "
                             "distance.")


def test_the_prior_gate_returns_exactly_the_rows_beyond_it_to_their_start():
    from sdm.experiments.gate import prior_gate

    start = torch.tensor([[0.5, 0.3], [0.5, 0.3], [0.0, 0.0], [1.0, 1.0]], dtype=torch.float64)
    # travels 0.29 (within 2 x 0.15), 0.4 (beyond), 0.09 (beyond 2 x 0.04) and 0.3 (not beyond: kept)
    theta = start + torch.tensor([[0.29, 0.0], [0.0, -0.4], [0.09, 0.0], [0.18, 0.24]], dtype=torch.float64)
    sd = torch.tensor([0.15, 0.15, 0.04, 0.15], dtype=torch.float64)
    gated, returned = prior_gate(theta, start, sd, 2.0)
    assert returned.tolist() == [False, True, True, False]
    assert torch.equal(gated[returned], start[returned]) and torch.equal(gated[~returned], theta[~returned])
    for bad in (0, -1.0, float("nan"), True):
        with pytest.raises(SDMInputError, match="gate"):
            prior_gate(theta, start, sd, bad)
    with pytest.raises(SDMInputError, match="sd"):
        prior_gate(theta, start, sd[:3], 2.0)


def test_each_row_is_gated_with_the_spread_its_theta_star_is_drawn_with(data):
    from sdm.experiments.gate import prior_sd
    from sdm import sharing as S

    truth = S.TruthDistribution(camera_sd=0.2, car_sd=0.15, residual_sd=0.05)
    for noise_level in ("configuration", "car", "camera+car"):
        sharing = S.sharing(noise_level, data)
        sd = prior_sd(sharing, truth)
        drawn = S.draw_truth(sharing, 5, truth) - torch.tensor(truth.centre, dtype=torch.float64)
        is_car = sharing.rows[:, 1] != S.NO_INDEX
        expected = {"configuration": torch.full_like(sd, 0.2), "car": torch.full_like(sd, 0.15),
                    "camera+car": torch.where(is_car, 0.05, 0.2).to(torch.float64)}[noise_level]
        assert torch.equal(sd, expected)
        if noise_level == "camera+car":  # the residual rows are drawn around zero, not around the centre
            drawn[is_car] += torch.tensor(truth.centre, dtype=torch.float64)
        assert (drawn.abs() <= 6 * sd.unsqueeze(1)).all()  # the spread it names is the one drawn with


def test_every_method_is_scored_after_the_gate_from_its_own_start(data):
    """A gate no unit passes leaves every distance as it is; a gate of 1e-9 sd returns every unit that moved to its
    method's start. The floor (given theta*) and the camera+car level (a unit is two rows) are not gated."""
    methods = ["sdm_paper", "sdm_schedule", "cmaes_car", "floor"]
    kept = objects_runs(data, "car", 0, [0], seed=3, settings=replace(SETTINGS, gate=1e6), methods=methods)
    returned = objects_runs(data, "car", 0, [0], seed=3, settings=replace(SETTINGS, gate=1e-9), methods=methods)
    scored = kept[~kept["method"].isin(["floor", "hidden"])]
    assert (scored["gated"] == scored["distance"]).all()
    moved = returned[~returned["method"].isin(["floor", "hidden"]) & (returned["distance"] != returned["start"])]
    assert set(moved["method"]) >= {"sdm_paper", "sdm_schedule", "cmaes_car"}
    assert (moved["gated"] - moved["start"]).abs().max() < 1e-12
    assert returned.loc[returned["method"] == "floor", "gated"].isna().all()
    pair = objects_runs(data, "camera+car", 0, [0], seed=3, settings=SETTINGS, methods=["sdm_paper"])
    assert pair["gated"].isna().all()
    table = table6([kept.assign(scale=1), returned.assign(scale=2)])
    sdm = table[(table["method"] == "sdm_schedule")].set_index("scale")
    assert sdm.loc[1, "gated_m"] == pytest.approx(sdm.loc[1, "mean_m"])
    assert sdm.loc[2, "gated_of_start"] <= 1.0 and table.loc[table["method"] == "floor", "gated_m"].isna().all()

"""Table 6's driver (sdm.objects) and its report (sdm.report.objects) on a few configurations."""
from __future__ import annotations

from dataclasses import replace

import pandas as pd
import pytest
import torch

from sdm.baselines.rows import RowsCMAESSettings, RowsFloorSettings
from sdm.baselines.silhouette import SilhouetteSettings
from sdm.errors import SDMInputError
from sdm.objects import METHODS, REFERENCES, ObjectsSettings, objects_runs, scaling_runs
from sdm.report.objects import scaling_table, table6, table6_summary, verdict_sentence
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
    frames = [objects_runs(data, level, noise, [0], seed=5, settings=SETTINGS)
              for level in ("configuration", "camera+car") for noise in (0, 1)]
    table = table6(frames, pd.DataFrame({"level": [0, 0, 1], "run": [0, 1, 0], "distance": [1e-3, 3e-3, 2e-2]}))
    shared = table[table["sharing"] == "shared"].set_index("level")
    assert shared.loc[0, "mean_m"] == pytest.approx(2e-3) and shared.loc[0, "units"] == 2
    rows = table[(table["sharing"] == "configuration") & (table["level"] == 1)].set_index("method")
    assert list(rows.index) == list(REFERENCES) + list(METHODS)
    own = frames[1][frames[1]["method"] == "cmaes"]["distance"]
    assert rows.loc["cmaes", "mean_m"] == pytest.approx(own.mean())
    words = table6_summary(table, None)
    assert "A configuration's shift" in words and "of its start's error" in words
    assert "the best peer" in verdict_sentence(table)
    old = table.drop(columns=["start_m", "of_start", "closer"])  # a snapshot made before the references
    old = old[old["method"].isin(METHODS) | (old["sharing"] == "shared")]
    assert "CMA-ES's mean distance" in verdict_sentence(old)


def test_scaling_gives_one_point_per_budget(data):
    from sdm.data import set_with_cars

    cars = set_with_cars(16, 2, seed=0)
    frame = scaling_runs(cars, 2, 0, [0], seed=1, settings=SETTINGS, epochs=[1, 2], budgets=[5])
    assert sorted(zip(frame["method"], frame["budget"])) == [("cmaes", 5), ("cmaes_car", 5), ("prior", 0),
                                                              ("sdm_paper", 1), ("sdm_paper", 2), ("start", 0)]
    fitted = frame[~frame["method"].isin(["prior"])]
    assert (fitted["cpu_s"] > 0).all()
    start = frame[frame["method"] == "start"].iloc[0]
    assert (frame["start"] == start["mean"]).all() and start["closer"] == 0.0
    assert "doing nothing" in table6_summary(table6([]), scaling_table([frame]))


def test_bad_level_and_method_are_named(data):
    with pytest.raises(SDMInputError, match="level must be one of"):
        objects_runs(data, "shared", 0, [0], seed=0, settings=SETTINGS)
    with pytest.raises(SDMInputError, match="methods must be of"):
        objects_runs(data, "car", 0, [0], seed=0, settings=SETTINGS, methods=["adam"])

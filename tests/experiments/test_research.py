"""Beyond the paper: the runs of Tables 4 and 5, the tables, their words, and the config section.

Small synthetic sets (tests/scenes.py) and short trainings; the workflow's end-to-end run of the
research stages is in test_workflow.py (the .test config switches both on).
"""
from __future__ import annotations

import math
import re
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
import yaml

from scenes import configuration_set
from sdm import FLOW_RULES, RULES, TrainSettings
from sdm.errors import SDMInputError
from sdm.train import parse_schedule
from sdm.mapping.research_rules import RESEARCH_RULES
from sdm.experiments import (
    DEPTH_RUN_COLUMNS, RUN_COLUMNS, depth_noise_runs, noise_runs, rule_noise_runs, run_seed,
)
from run_reference import depth_noise_run, noise_run
from sdm.experiments import paper
from sdm.experiments.report.depth import DEPTH_BAR_M, depth_figure, table5_bias_summary, table5_frame, table5_summary, write_table5
from sdm.experiments.report.research import (
    beyond_the_paper, half_paper_mean_m, rules_against_baselines, rules_figure, table4_frame, table4_summary, rule_times,
    write_table4,
)

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "workflow" / "scripts"))
from config_check import ConfigError, check_config, validate_schema  # noqa: E402

SHIFT = (0.517, 0.303)
SETTINGS = TrainSettings(lr=3e-4, n_epoch=1, batch_size=4, s=4, seed=7)


@pytest.fixture(scope="module")
def small_set():
    return configuration_set(8, seed=3)


# -- the runs --------------------------------------------------------------------------------------------


def test_rule_noise_runs_are_table2_runs_with_the_rule_and_the_same_draws(small_set):
    table = rule_noise_runs(small_set, "closed", 2, [0, 3], SETTINGS, shift=SHIFT)
    assert list(table.columns) == ["rule", *RUN_COLUMNS]
    assert set(table["rule"]) == {"closed"}
    for row in table.drop(columns="rule").to_dict("records"):  # each run is the run trained alone with the rule
        assert row == noise_run(small_set, 2, row["run"], replace(SETTINGS, rule="closed"), shift=SHIFT)
    # The seeds (noise draw and shuffling) are Table 2's: they do not depend on the rule.
    paper_rule = noise_runs(small_set, 2, [0, 3], SETTINGS, shift=SHIFT)
    assert table["seed"].tolist() == paper_rule["seed"].tolist() == [run_seed(7, 2, 0), run_seed(7, 2, 3)]
    assert table["distance"].tolist() != paper_rule["distance"].tolist()  # another rule, another result


def test_depth_noise_runs_equal_the_runs_trained_alone(small_set):
    """Run r: targets of (a*, b*, c*), Table 2's noise draw of (seed, level, r), fit_depth trained with that
    seed (tests/run_reference.py), batched (two groups: 2 runs, then 1): the depth flow is a float sum,
    so a packed run may round it otherwise, held to 1e-12 m (as test_depth.py holds train_runs)."""
    c, noise_level = 0.5, 1
    table = depth_noise_runs(small_set, c, noise_level, [2, 0, 1], SETTINGS, shift=SHIFT, group_size=2)
    assert list(table.columns) == DEPTH_RUN_COLUMNS and table["run"].tolist() == [2, 0, 1]
    for row in table.to_dict("records"):
        alone = depth_noise_run(small_set, c, noise_level, row["run"], SETTINGS, shift=SHIFT)
        assert {key: row[key] for key in ("c_true", "noise_level", "run", "seed")} == {
            key: alone[key] for key in ("c_true", "noise_level", "run", "seed")}
        assert row["seed"] == run_seed(SETTINGS.seed, noise_level, row["run"])
        for key in DEPTH_RUN_COLUMNS[4:]:
            assert abs(row[key] - alone[key]) <= 1e-12, key
        assert abs(alone["c"]) > 1e-3  # c moved: the comparison is not between two zeros
    assert table["c"].nunique() == 3  # each run its own
    again = depth_noise_runs(small_set, c, noise_level, [2, 0, 1], SETTINGS, shift=SHIFT, group_size=2)
    pd.testing.assert_frame_equal(table, again)  # deterministic from the seed


def test_depth_noise_runs_move_c_towards_the_truth(small_set):
    """Noise-free, the fit leaves (0, 0, 0) for c*: c ends on the side of c* (a short run, not converged)."""
    for c in (-1.0, 1.0):
        row = depth_noise_runs(small_set, c, 0, [0], replace(SETTINGS, n_epoch=2), shift=SHIFT).iloc[0]
        assert np.sign(row["c"]) == np.sign(c) and row["error_c"] < abs(c)


def test_depth_noise_runs_refuse_bad_shifts(small_set):
    with pytest.raises(SDMInputError, match="shift"):
        depth_noise_runs(small_set, 1.0, 0, [0], SETTINGS, shift=(0.5, 0.3, 0.0))
    with pytest.raises(SDMInputError, match="finite"):
        depth_noise_runs(small_set, math.inf, 0, [0], SETTINGS, shift=SHIFT)
    nearest = float(small_set.points[:, 2].min())
    with pytest.raises(SDMInputError, match="^c = .* behind the camera"):  # the nearest point moved behind it
        depth_noise_runs(small_set, -nearest, 0, [0], SETTINGS, shift=SHIFT)


# -- Table 4 ----------------------------------------------------------------------------------------------


def _runs(noise_levels, runs, scale, rule=None, seed=0):
    generator = np.random.default_rng(seed)
    rows = [{"noise_level": noise_level, "run": run, "distance": scale * (noise_level + 1) * generator.uniform(0.5, 1.5)}
            for noise_level in noise_levels for run in runs]
    frame = pd.DataFrame(rows)
    if rule:
        frame.insert(0, "rule", rule)
    return frame


def test_rules_beside_the_baselines_are_compared_on_the_same_runs_only():
    """Only the rule's own (level, run) pairs of each baseline count; a baseline missing one of them is left out."""
    rules = _runs([0, 1], range(3), 2e-3, "closed", seed=2)
    good = _runs([0, 1], range(6), 1e-3, seed=4)
    good.insert(0, "method", "cmaes")
    # runs 3..5 of the slow baseline are far better, but are not the rule's runs: they must not count
    slow = _runs([0, 1], range(6), 1e-2, seed=5)
    slow.insert(0, "method", "chamfer")
    slow.loc[slow["run"] >= 3, "distance"] = 0.0
    partial = _runs([0, 1], range(2), 1e-6, seed=6)  # lacks run 2: not paired, left out
    partial.insert(0, "method", "sinkhorn")
    words = rules_against_baselines(rules, pd.concat([good, slow, partial], ignore_index=True))
    for noise_level in (0, 1):
        own = rules.loc[rules["noise_level"] == noise_level, "distance"].mean()
        best = good.loc[(good["noise_level"] == noise_level) & (good["run"] < 3), "distance"].mean()
        assert f"level {noise_level}: {1e3 * own:.3f} against {1e3 * best:.3f} for `cmaes`, the best baseline (beats 1 of 2)" in words
    assert "sinkhorn" not in words and "does not beat every baseline" in words
    assert rules_against_baselines(rules, good.assign(noise_level=5)) == ""  # no level in common: nothing to say


def test_table4_pairs_each_rule_with_table2_runs_of_the_same_draws():
    table2 = _runs([0, 1, 2], range(6), 1e-2, seed=1)
    rules = pd.concat([_runs([0, 1, 2], range(4), 2e-3, "closed", seed=2),
                       _runs([0, 1, 2], range(4), 5e-2, "nearest", seed=3)])
    table = table4_frame(rules, table2)
    assert table[["rule", "noise_level"]].values.tolist() == [[f, lv] for f in ("closed", "nearest") for lv in (0, 1, 2)]
    for row in table.itertuples():
        ours = rules[(rules["rule"] == row.rule) & (rules["noise_level"] == row.noise_level)]["distance"]
        theirs = table2[(table2["noise_level"] == row.noise_level) & (table2["run"] < 4)]["distance"]  # runs 4, 5 unpaired
        assert row.runs == 4 and row.paper_rule_runs == 4
        assert row.mean_m == pytest.approx(ours.mean()) and row.std_m == pytest.approx(ours.std())
        assert row.median_m == pytest.approx(ours.median())
        assert row.paper_rule_mean_m == pytest.approx(theirs.mean())
        assert row.ratio_to_paper_rule == pytest.approx(ours.mean() / theirs.mean())
        published = paper.TABLE2[row.noise_level]["mean"] * 1e-3
        assert row.published_mean_m == pytest.approx(published)
        assert row.bar_m == pytest.approx(published if row.noise_level == 0 else published / 2)
        assert row.meets_bar == (ours.mean() <= row.bar_m)
    assert half_paper_mean_m(1) == pytest.approx(8.17e-3) and math.isnan(half_paper_mean_m(9))


def test_table4_summary_names_misses_and_numbers():
    table2 = _runs([0, 1], range(3), 1e-2)
    good = _runs([0, 1], range(3), 1e-4, "closed")
    bad = _runs([0, 1], range(3), 1.0, "nearest")
    table = table4_frame(pd.concat([good, bad]), table2)
    words = table4_summary(table)
    assert "`closed` (3 runs per level) meets the bar (half the paper's mean) at every level run (2 of 2)" in words
    assert "`nearest` (3 runs per level) misses the bar (half the paper's mean) at level 0, 1" in words
    row = table[(table["rule"] == "closed") & (table["noise_level"] == 1)].iloc[0]
    assert f"{1e3 * row.mean_m:.3f}" in words and f"{1e3 * row.paper_rule_mean_m:.3f}" in words


def test_table4_refuses_runs_without_the_columns():
    with pytest.raises(SDMInputError, match="rule"):
        table4_frame(_runs([0], range(2), 1e-3), _runs([0], range(2), 1e-3))


# -- Table 5 ----------------------------------------------------------------------------------------------


def _depth_runs(errors_by_cell):
    rows = []
    for (c_true, noise_level), (ea, eb, ec) in errors_by_cell.items():
        for run, factor in enumerate((0.5, 1.5)):
            a, b, c = ea * factor, eb * factor, ec * factor
            rows.append({"c_true": c_true, "noise_level": noise_level, "run": run, "c": c_true - c, "error_a": a, "error_b": b,
                         "error_c": c,
                         "distance_ab": math.hypot(a, b), "distance": math.sqrt(a * a + b * b + c * c)})
    return pd.DataFrame(rows)


def test_table5_means_and_the_noise_free_bar():
    runs = _depth_runs({(-1.0, 0): (1e-3, 3e-3, 1e-2), (1.0, 0): (1e-3, 1e-3, 1e-2), (1.0, 2): (1e-4, 1e-4, 1e-4)})
    table = table5_frame(runs)
    assert table[["c_true", "noise_level"]].values.tolist() == [[-1.0, 0], [1.0, 0], [1.0, 2]]
    for row in table.itertuples():
        cell = runs[(runs["c_true"] == row.c_true) & (runs["noise_level"] == row.noise_level)]
        for axis in "abc":
            assert getattr(row, f"error_{axis}_m") == pytest.approx(cell[f"error_{axis}"].mean())
        assert row.distance_m == pytest.approx(cell["distance"].mean()) and row.runs == 2
        assert row.bias_c_m == pytest.approx(-cell["error_c"].mean())  # every run's c is too near here
        within = all(getattr(row, f"error_{axis}_m") <= DEPTH_BAR_M[axis] for axis in "abc")
        assert row.meets_bar == (row.noise_level == 0 and within)
    assert table["meets_bar"].tolist() == [False, True, False]  # b misses at c* = -1; level 2 has no bar
    words = table5_summary(table)
    assert "c* = -1 m (2 runs per level)" in words and "misses the bar" in words and "meets the bar" in words
    assert "level 2" in words


def test_depth_bias_measures_the_depth_flow_at_theta_star(small_set):
    """Noise-free, theta* is a fixed point at zooms 1 and 0 (no pull on c); under noise the flow, its edge share
    and the unmatched shares are what one layer call over the whole set gives (the batches only split the sums)."""
    from sdm.depth import depth_flow, depth_targets
    from sdm.experiments import DEPTH_BIAS_COLUMNS, depth_bias, noisy_targets
    from sdm.mapping import SpatialDomainMapping
    from sdm.sky import shift_vector

    clean = depth_bias(small_set, 0.5, [0], 7, zooms=[1, 0], shift=SHIFT, batch_size=3)
    assert list(clean.columns) == DEPTH_BIAS_COLUMNS and clean["flow_c"].tolist() == [0.0, 0.0]
    noisy = depth_bias(small_set, 0.5, [2], 7, schedule="closed_centred_r1+group_crossing:2", zooms=[0], shift=SHIFT,
                       batch_size=3).iloc[0]
    truth = (*SHIFT, 0.5)
    targets = noisy_targets(depth_targets(small_set, truth), 2, run_seed(7, 2, 0))
    batch = small_set.with_targets(targets).batch(torch.arange(len(small_set)))
    points = batch.points + shift_vector(truth, batch.points)
    layer = SpatialDomainMapping(small_set.camera, s=4, zoom=0, rule="group_crossing")
    result = layer(points, batch.pixels, batch.targets, batch.config, batch.rank).result
    assert noisy["flow_c"] == pytest.approx(float(depth_flow(points, result.flow).sum()) / len(small_set), abs=1e-12)
    assert noisy["flow_c"] != 0 and math.isfinite(noisy["offset_c"]) and 0 <= noisy["unmatched_edge"] <= 1
    words = table5_bias_summary(table5_frame(_depth_runs({(0.5, 2): (1e-3, 1e-3, 1e-2)})),
                                pd.DataFrame([noisy.to_dict() | {"rule": "group_crossing"}]))
    assert words.startswith("- c* = 0.5 m, level 2 (1e-3 m): mean c - c* -10.00; group_crossing at zoom 0:")


def test_tables_are_written_and_drawn(tmp_path):
    table4 = table4_frame(_runs([0, 1], range(3), 1e-3, "closed"), _runs([0, 1], range(3), 1e-2))
    table5 = table5_frame(_depth_runs({(0.5, 0): (1e-3, 1e-3, 1e-2), (0.5, 1): (2e-3, 2e-3, 2e-2)}))
    for frame, which, write in ((table4, 4, write_table4), (table5, 5, write_table5)):
        written = write(frame, tmp_path / f"table{which}")
        assert [p.suffix for p in written] == [".csv", ".md", ".tex", ".html"] and all(p.stat().st_size for p in written)
        assert pd.read_csv(written[0]).shape == frame.shape
    assert "| closed |" in (tmp_path / "table4.md").read_text()
    for fig in (rules_figure(table4), depth_figure(table5)):
        assert fig.axes
    assert beyond_the_paper() == ""
    section = beyond_the_paper("T4", "words 4")
    assert section.startswith("\n## Beyond the paper") and "words 4" in section and "Table 5" not in section


# -- the config section -----------------------------------------------------------------------------------


def _config() -> dict:
    return yaml.safe_load((ROOT / "config.yaml").read_text())


def test_the_schema_lists_the_library_rules():
    """The workflow does not import sdm at parse time: its rule names are the schema's, held here to the names
    the library accepts: the one registry, sdm.RULES (the product's rules and the experiments)."""
    schema = yaml.safe_load((ROOT / "workflow" / "schemas" / "config.schema.yaml").read_text())
    research = schema["properties"]["research"]["properties"]
    accepted = sorted(RULES)
    assert sorted(research["rules"]["properties"]["names"]["items"]["anyOf"][0]["enum"]) == accepted
    assert research["depth"]["properties"]["schedule"]["allOf"] == [research["rules"]["properties"]["names"]["items"]]
    for name in accepted:
        TrainSettings(rule=name)


def test_the_public_registry_holds_the_rules_the_configuration_trains_with():
    """sdm.FLOW_RULES: the paper's rule (Table 2) and the ones config.yaml's Tables 4 and 5 train with; every
    other rule is an experiment, in RESEARCH_RULES only."""
    research = _config()["research"]
    trained = set()
    for name in [research["depth"]["schedule"], *research["rules"]["names"]]:
        rule, refine = parse_schedule(name)
        trained |= {rule, refine.rule} if refine else {rule}
    assert set(FLOW_RULES) == {"paper", *trained}
    assert not set(FLOW_RULES) & set(RESEARCH_RULES)


def test_the_schema_defaults_are_the_rules_config_yaml_names():
    """A config without research.rules / research.depth.schedule trains with the rules config.yaml names."""
    config, defaulted = _config(), _config()
    del defaulted["research"]
    validate_schema(defaulted)
    assert defaulted["research"]["rules"]["names"] == config["research"]["rules"]["names"]
    assert defaulted["research"]["depth"]["schedule"] == config["research"]["depth"]["schedule"]
    del config["research"]["depth"]["schedule"]  # the key's own default, the section present
    validate_schema(config)
    assert config["research"]["depth"]["schedule"] == defaulted["research"]["depth"]["schedule"]


@pytest.mark.parametrize(
    "change, key",
    [
        ({"rules": {"names": ["closedd"]}}, "research.rules.names[0]"),
        ({"rules": {"names": ["paper"]}}, "research.rules.names"),
        ({"rules": {"names": ["closed_centred_r1+closedd:4"]}}, "research.rules.names[0]"),
        ({"rules": {"names": ["closed_centred_r1", "closed+group_crossing:0"]}}, "research.rules.names[1]"),
        ({"rules": {"runs": 61}}, "research.rules.runs"),
        ({"rules": {"runs": 0}}, "research.rules.runs"),
        ({"depth": {"enabled": True, "shifts_c": [1.0, float("inf")]}}, "research.depth.shifts_c[1]"),
        ({"depth": {"enabled": True, "shifts_c": []}}, "research.depth.shifts_c"),
        ({"depth": {"enabled": True, "noise_levels": [-1]}}, "research.depth.noise_levels[0]"),
        ({"depth": {"enabled": True, "schedule": "smooth"}}, "research.depth.schedule"),
        ({"depth": {"enabled": True, "schedule": "closed_centred_r1+smooth:4"}}, "research.depth.schedule"),
    ],
)
def test_bad_research_values_are_refused_naming_the_key(change, key):
    config = _config()
    for part, values in change.items():
        config["research"][part].update(values)
    with pytest.raises(ConfigError, match=re.escape(f"config key '{key}'")):
        validate_schema(config)
        check_config(config)


def test_a_config_without_the_research_section_is_valid_with_both_off():
    config = _config()
    del config["research"]
    validate_schema(config)
    check_config(config)
    assert not config["research"]["rules"]["enabled"] and not config["research"]["depth"]["enabled"]


def test_rule_times_set_each_rule_beside_the_paper_rule_with_the_bar():
    runs = pd.DataFrame({"rule": ["fast"] * 2 + ["slow"] * 2, "noise_level": [0, 1, 0, 1], "run": [0, 0, 0, 0],
                         "distance": [1e-3] * 4, "seconds": [0.10, 0.14, 0.30, 0.34]})
    text = rule_times(runs, [{"runs": 60, "seconds": 6.0}, {"runs": 40, "seconds": 4.0}])
    fast, slow = text.strip().splitlines()
    assert fast.startswith("- time per run of rule `fast`: 0.120 s against 0.100 s") and "1.20x: within" in fast
    assert slow.startswith("- time per run of rule `slow`: 0.320 s against 0.100 s") and "3.20x: beyond" in slow
    assert rule_times(runs.drop(columns="seconds"), [{"runs": 1, "seconds": 1.0}]) == ""
    assert rule_times(runs, []) == ""

"""sdm.experiments.report and sdm.experiments: tables beside the paper, writers, report text, figures, runs and seeds."""
import math

import pandas as pd
import pytest
import torch

from scenes import configuration_set, configurations
from sdm.errors import SDMInputError
from sdm.experiments import noise_runs, noisy_targets, run_seed, settings_for, split_indices, tune_cell
from sdm.experiments import paper
from sdm.experiments.report import figures
from sdm.experiments.report.io import read_json, write_json
from sdm.experiments.report.reproduction import build_report, checks
from sdm.experiments.report.tables import (
    TABLE1_FORMAT,
    TABLE2_FORMAT,
    best_cell,
    table1_frame,
    table2_frame,
    to_latex,
    to_markdown,
    write_table,
)
from sdm.sky import SKY_SHIFT

CONFIG = {
    "data": {"source": "synthetic", "synthetic": {"n_images": 5277, "seed": 0}},
    "sky": {"n_images": 4248, "shift": list(SKY_SHIFT), "seed": 0},
    "split": {"n_selected": 768, "n_train": 512, "n_dev": 256, "seed": 0},
    "train": {"s": 4, "batch_size": 16, "lr_decay": 0.5, "seed": 0},
    "tuning": {"n_epoch": [1, 2], "lr": [1e-4, 3e-4, 1e-3]},
    "noise": {"levels": [0, 1, 2, 3, 4], "runs": 60, "chunk_size": 30, "seed": 0},
    "figures": {"example": 0, "seed": 0},
}


def grid(losses=None) -> pd.DataFrame:
    losses = losses or {(1, 1e-4): 5.0, (1, 3e-4): 0.8, (1, 1e-3): 1.1, (2, 1e-4): 1.2, (2, 3e-4): 0.9, (2, 1e-3): 1.3}
    return pd.DataFrame(
        [{"n_epoch": n, "lr": lr, "dev_loss": loss, "distance": 1e-3 * loss} for (n, lr), loss in losses.items()]
    )


def distances(means_mm=(0.5, 20.0, 30.0, 40.0, 50.0), runs=6) -> pd.DataFrame:
    rows = []
    for noise_level, mean in enumerate(means_mm):
        for run in range(runs):
            d = 1e-3 * mean * (0.8 + 0.4 * run / (runs - 1))
            rows.append({"noise_level": noise_level, "run": run, "seed": run, "a": SKY_SHIFT[0] + d, "b": SKY_SHIFT[1], "distance": d})
    return pd.DataFrame(rows)


# -- Table 1 -------------------------------------------------------------------------------------


def test_table1_puts_the_paper_beside_ours_and_marks_both_picks():
    table = table1_frame(grid().sample(frac=1, random_state=0))
    assert list(zip(table["n_epoch"], table["lr"])) == list(paper.TABLE1)
    assert table["paper_dev_loss"].tolist() == list(paper.TABLE1.values())
    assert table.loc[table["best"], ["n_epoch", "lr"]].values.tolist() == [[1, 3e-4]]
    assert table.loc[table["paper_best"], ["n_epoch", "lr"]].values.tolist() == [[1, 3e-4]]
    assert table["distance_mm"].tolist() == pytest.approx((grid()["distance"] * 1000).tolist())
    assert best_cell(grid()) == {"n_epoch": 1, "lr": 3e-4, "dev_loss": 0.8}


def test_table1_cells_outside_the_paper_have_no_paper_value():
    frame = pd.DataFrame([{"n_epoch": 3, "lr": 5e-4, "dev_loss": 2.0}])
    table = table1_frame(frame)
    assert math.isnan(table["paper_dev_loss"].iloc[0]) and not table["paper_best"].iloc[0]
    assert "| 3 | 5e-04 | 2.000 | - |" in to_markdown(table, TABLE1_FORMAT)


def test_table1_rejects_a_grid_without_dev_loss():
    with pytest.raises(SDMInputError, match="dev_loss"):
        table1_frame(pd.DataFrame([{"n_epoch": 1, "lr": 1e-4}]))


# -- Table 2 -------------------------------------------------------------------------------------


def test_table2_statistics_in_millimetres_beside_the_paper():
    runs = distances()
    table = table2_frame(runs, {1: 283.0, 2: 494.0, 3: 700.0, 4: 905.0})
    assert table["noise_level"].tolist() == [0, 1, 2, 3, 4] and set(table["runs"]) == {6}
    level1 = 1000 * runs.loc[runs["noise_level"] == 1, "distance"]
    row = table.set_index("noise_level").loc[1]
    assert row["mean"] == pytest.approx(level1.mean())
    assert row["std"] == pytest.approx(level1.std(ddof=1))
    assert row[["q1", "q2", "q3"]].tolist() == pytest.approx(level1.quantile([0.25, 0.5, 0.75]).tolist())
    assert row["paper_mean"] == paper.TABLE2[1]["mean"] and row["paper_q3"] == paper.TABLE2[1]["q3"]
    assert row["mean_ratio"] == pytest.approx(row["mean"] / paper.TABLE2[1]["mean"])
    assert table["avg_dist_mm"].tolist() == [0.0, 283.0, 494.0, 700.0, 905.0]
    assert table["paper_avg_dist_mm"].tolist() == [0.0, 283.4, 494.6, 699.8, 904.8]


def test_writers_produce_csv_markdown_and_latex(tmp_path):
    table = table2_frame(distances(), {1: 283.0, 2: 494.0, 3: 700.0, 4: 905.0})
    paths = write_table(table, tmp_path / "tables" / "table2", TABLE2_FORMAT)
    assert [p.name for p in paths] == ["table2.csv", "table2.md", "table2.tex", "table2.html"]
    page = paths[3].read_text()  # the Markdown as a page: every row a row of its table, numbers as in the .md
    assert page.count("<tr>") == 1 + len(table) and ">283.0</td>" in page and page.count("<table>") == 1
    assert pd.read_csv(paths[0])["mean"].tolist() == pytest.approx(table["mean"].tolist())
    markdown = paths[1].read_text()
    lines = [line for line in markdown.splitlines() if line.startswith("|")]
    assert len(lines) == 2 + len(table)
    assert all(line.count("|") == len(TABLE2_FORMAT.columns) + 1 for line in lines)
    assert "| 1 | 6 | 283.0 | 283.4 |" in markdown  # ints stay ints
    latex = paths[2].read_text()
    assert latex.count(r"\\") == 1 + len(table)
    assert r"\begin{tabular}{|" + "|".join("c" * len(TABLE2_FORMAT.columns)) + "|}" in latex
    assert "||theta\\textasciitilde{} - theta*||" in to_latex(table, TABLE2_FORMAT)
    # the title renders bold as a whole, its theta~ and theta* as written (a bare * closed the bold early)
    assert f"<strong>{TABLE2_FORMAT.caption}</strong>" in page
    assert markdown.startswith("**Table 2: distance ||theta\\~ - theta\\*|| per noise level")
    assert not list(tmp_path.glob("tables/.*"))  # no temporary file left behind


def test_json_round_trip_is_atomic(tmp_path):
    path = write_json(tmp_path / "a" / "b.json", {"x": [1, 2]})
    assert read_json(path) == {"x": [1, 2]}
    assert [p.name for p in path.parent.iterdir()] == ["b.json"]


# -- the reproduction report ---------------------------------------------------------------------


def test_checks_apply_the_acceptance_criteria():
    table1 = table1_frame(grid())
    good = table2_frame(distances((0.6, 16.0, 25.0, 35.0, 40.0)), {})
    assert all(c.passed for c in checks(table1, good))
    bad = table2_frame(distances((1.5, 40.0, 25.0, 10.0, 40.0)), {})
    results = {c.name: c.passed for c in checks(table1_frame(grid({(1, 3e-4): 2.0, (1, 1e-3): 1.0})), bad)}
    assert results == {
        "Table 2, level 0: mean distance": False,
        "Table 2, level 1: mean / paper's": False,
        "Table 2, level 2: mean / paper's": True,
        "Table 2, level 3: mean / paper's": False,
        "Table 2, level 4: mean / paper's": True,
        "Table 1: best cell": False,
    }


def test_report_is_written_from_the_measured_numbers():
    runs = distances((0.77, 41.0, 25.0, 35.0, 40.0))
    table1 = table1_frame(grid({(1, 3e-4): 2.5, (1, 1e-3): 1.25}))
    table2 = table2_frame(runs, {1: 271.1, 2: 473.2, 3: 669.5, 4: 865.6})
    stats = {"target_mean_depth": 48.76, "configurations": 4248, "circle_overlap_rate": 0.3}
    text = build_report(table1, table2, runs, stats, {"images": 5277, "cars_per_image": 11.37}, CONFIG)
    assert "**4 of 6 criteria pass.**" in text
    for number in ("0.770", "41.000", "2.51x", "271.1", "48.76", "11.37", "2.500", "1.250"):
        assert number in text, number
    assert "  - level 1: 41.000e-3 m = 2.51x the paper's 16.340e-3 m" in text
    assert "pulled to one side (a~ above a*" in text
    assert "Table 1 picks another cell" in text
    assert "0.957x" in text  # Avg. Dist. ratio explained by the depth ratio 48.76 / 50.95
    assert text.count("| FAIL |") == 2


def _rendered_reports() -> list[str]:
    """The report rendered through build_report on every branch of its text: criteria met and missed (noise-free
    too far, noisy means above and below the paper's), Table 1's pick the paper's or another."""
    stats = {"target_mean_depth": 48.76, "configurations": 4248, "circle_overlap_rate": 0.3}
    summary = {"images": 5277, "cars_per_image": 11.37}
    texts = []
    for means, losses in [((0.6, 16.0, 25.0, 35.0, 40.0), None), ((0.77, 41.0, 25.0, 35.0, 40.0),
                                                                   {(1, 3e-4): 2.5, (1, 1e-3): 1.25}),
                          ((1.5, 40.0, 12.0, 10.0, 90.0), {(1, 3e-4): 2.0, (1, 1e-3): 1.0})]:
        runs = distances(means)
        table2 = table2_frame(runs, {1: 271.1, 2: 473.2, 3: 669.5, 4: 865.6})
        texts.append(build_report(table1_frame(grid(losses)), table2, runs, stats, summary, CONFIG))
    return texts


def test_the_rendered_report_speaks_of_the_method_alone():
    """The guard reads the report as rendered (tests/wording.py's phrases), not reproduction.py's source: a phrase
    split across string literals is in the text a reader gets, and only the rendered text shows it."""
    from wording import forbidden_in

    texts = _rendered_reports()
    assert len({text.count("| FAIL |") for text in texts}) == 3  # three different branches rendered
    assert [forbidden_in(text) for text in texts] == [[], [], []]


def test_a_phrase_split_across_literals_is_caught_in_the_rendered_text_only(tmp_path, monkeypatch):
    """The negative control: a forbidden phrase written as two literals passes a scan of the source and is found in
    the rendered report."""
    from sdm.experiments.report import reproduction
    from wording import forbidden_in, offences

    source = tmp_path / "split.py"
    source.write_text('def contrast(*_):\n    return ("as the issue"\n            " 12 bar set.")\n')
    assert offences([source], tmp_path) == []  # the source scan misses it
    namespace = {}
    exec(source.read_text(), namespace)
    monkeypatch.setattr(reproduction, "_data_contrast", namespace["contrast"])
    found = [forbidden_in(text) for text in _rendered_reports()]
    assert any(phrases and phrases[0][1].startswith("issue") for phrases in found), found


# -- experiments -----------------------------------------------------------------------------------


def test_run_seeds_are_deterministic_and_distinct():
    seeds = {run_seed(0, noise_level, run) for noise_level in range(5) for run in range(60)}
    assert len(seeds) == 300
    assert run_seed(0, 2, 7) == run_seed(0, 2, 7) != run_seed(1, 2, 7)
    with pytest.raises(SDMInputError, match="noise_level"):
        run_seed(0, -1, 0)


def test_split():
    split = split_indices(50, 20, 10, seed=1)
    assert len(split["train"]) == 20 and len(split["dev"]) == 10
    assert not set(split["train"]) & set(split["dev"])
    assert sorted(split["train"] + split["dev"]) == split["selected"]
    with pytest.raises(SDMInputError):
        split_indices(20, 15, 10, seed=0)


def test_noise_run_is_reproducible_and_noise_moves_targets():
    data = configuration_set(32, seed=5)
    settings = settings_for(1, 1e-3, 4, 16, 0.5, 0)
    first = noise_runs(data, 2, [0], settings).iloc[0].to_dict()
    assert first == noise_runs(data, 2, [0], settings).iloc[0].to_dict()
    assert first["seed"] == run_seed(0, 2, 0) and first["distance"] == pytest.approx(
        math.hypot(first["a"] - SKY_SHIFT[0], first["b"] - SKY_SHIFT[1]))
    assert torch.equal(noisy_targets(data.targets, 0, 1), data.targets)
    assert not torch.equal(noisy_targets(data.targets, 2, 1), data.targets)


def test_tune_cell_reports_dev_loss_and_history():
    data = configuration_set(48, seed=6)
    train_set, dev_set = data.subset(range(32)), data.subset(range(32, 48))
    record, history = tune_cell(train_set, dev_set, settings_for(1, 1e-3, 4, 16, 0.5, 0))
    assert record["dev_loss"] >= 0 and record["n_epoch"] == 1 and record["lr"] == 1e-3
    assert record["steps"] == len(history) == 5 * 2  # 5 levels x 2 batches of 16
    assert {"step", "zoom", "a", "b"} <= set(history.columns)


# -- figures ---------------------------------------------------------------------------------------


@pytest.mark.slow
def test_importing_figures_leaves_the_backend_alone():
    """Forcing Agg at import hid every plot from the rendered notebooks (the inline backend must win)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    code = ("import matplotlib; matplotlib.use('svg'); import sdm.experiments.report.figures; "
            "print(matplotlib.get_backend())")
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[3] / "src"))
    env.pop("MPLBACKEND", None)
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "svg"


@pytest.mark.slow
def test_show_figure_saves_and_closes_outside_a_notebook(tmp_path):
    import matplotlib.pyplot as plt

    figure = figures.figure4(configurations(1, seed=2)[0].target, noise_levels=(0, 1))
    assert figures.show_figure(figure, tmp_path / "fig4.png", pdf=True) == tmp_path / "fig4.png"
    assert (tmp_path / "fig4.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and (tmp_path / "fig4.pdf").stat().st_size
    assert not plt.fignum_exists(figure.number)
    other = figures.figure4(configurations(1, seed=2)[0].target, noise_levels=(0,))
    assert figures.show_figure(other) is None and not plt.fignum_exists(other.number)


@pytest.mark.slow
def test_figures_render_and_save(tmp_path):
    import matplotlib.pyplot as plt

    configuration = configurations(1, seed=2)[0]
    data = configuration_set(32, seed=2)
    _, history = tune_cell(data, data, settings_for(1, 1e-3, 4, 16, 0.5, 0))
    point, pixel, info = figures.pick_point(configuration, SKY_SHIFT)
    original = configuration.points()[(configuration.pixels == torch.tensor(pixel)).all(1)][0]
    unmatched = figures.pick_point(configuration, (0.0, 0.0), matched=False)
    assert not unmatched[2]["matched"] and unmatched[2]["pull"].abs().sum() > 0
    made = {
        "fig1": figures.figure1(configuration),
        "fig2": figures.figure2(point, original, info),
        "fig3": figures.figure3(unmatched[0], unmatched[2]),
        "fig4": figures.figure4(configuration.target),
        "theta": figures.theta_path_figure(history),
        "distances": figures.distances_figure(distances()),
    }
    for name, figure in made.items():
        path = figures.save_figure(figure, tmp_path / f"{name}.png", pdf=name == "fig1")
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert not plt.fignum_exists(figure.number)  # closed: memory stays flat over many figures
    assert (tmp_path / "fig1.pdf").stat().st_size > 0


def test_flow_at_the_true_shift_vanishes_without_noise_and_is_reported():
    from scenes import configuration_set

    from sdm.experiments import flow_at_true_shift

    train_set = configuration_set(48, seed=9)
    flow = flow_at_true_shift(train_set, [0, 2], seed=0, s=4)
    assert list(flow["zoom"][flow["noise_level"] == 0]) == [4, 3, 2, 1, 0]
    noise_free = flow[flow["noise_level"] == 0]
    assert not noise_free[["flow_a", "flow_b", "unmatched"]].to_numpy().any()  # theta* is a fixed point
    noisy_finest = flow[(flow["noise_level"] == 2) & (flow["zoom"] == 0)].iloc[0]
    assert noisy_finest["unmatched"] > 0.05 and (noisy_finest["flow_a"], noisy_finest["flow_b"]) != (0, 0)

    runs = distances((0.77, 41.0, 25.0, 35.0, 40.0))
    table1 = table1_frame(grid({(1, 3e-4): 2.5, (1, 1e-3): 1.25}))
    table2 = table2_frame(runs, {1: 271.1, 2: 473.2, 3: 669.5, 4: 865.6})
    stats = {"target_mean_depth": 48.76, "configurations": 4248, "circle_overlap_rate": 0.3}
    text = build_report(table1, table2, runs, stats, {"images": 5277, "cars_per_image": 11.37}, CONFIG,
                        flow_at_truth=flow)
    assert "## Why the noisy runs are biased: the flow at theta*" in text
    assert "Without noise the flow at theta* is zero at zoom 0" in text
    assert f"{100 * noisy_finest['unmatched']:.1f}%" in text


def test_table3_sdm_rows_are_table2_runs_with_the_noise_jobs_seconds():
    """Table 3's SDM rows: the wanted (level, run) of Table 2 as they are, seconds = level's chunk seconds / runs."""
    from sdm.experiments.report.baselines import RUN_COLUMNS, table2_runs

    table2 = pd.DataFrame({"noise_level": [0, 0, 0, 1, 1, 1], "run": [0, 1, 2, 0, 1, 2], "seed": [10, 11, 12, 13, 14, 15],
                           "a": [0.5, 0.51, 0.52, 0.6, 0.61, 0.62], "b": [0.3] * 6,
                           "distance": [0.01, 0.02, 0.03, 0.04, 0.05, 0.06]})
    timings = [{"noise_level": 0, "runs": 2, "seconds": 3.0}, {"noise_level": 0, "runs": 1, "seconds": 3.0},
               {"noise_level": 1, "runs": 3, "seconds": 1.5}]
    rows = table2_runs(table2, timings, noise_levels=[0, 1], runs=[0, 1])
    assert set(RUN_COLUMNS) <= set(rows.columns) and set(rows["method"]) == {"sdm"}
    assert list(zip(rows["noise_level"], rows["run"])) == [(0, 0), (0, 1), (1, 0), (1, 1)]
    assert list(rows["distance"]) == [0.01, 0.02, 0.04, 0.05] and list(rows["a"]) == [0.5, 0.51, 0.6, 0.61]
    assert list(rows["seconds"]) == [2.0, 2.0, 0.5, 0.5]  # (3 + 3) s / 3 runs; 1.5 s / 3 runs
    assert table2_runs(table2, [], [1], [2])["seconds"].isna().all()  # no timing: no seconds, not zero
    with pytest.raises(SDMInputError, match="baselines.runs"):
        table2_runs(table2, timings, noise_levels=[0], runs=[0, 3])

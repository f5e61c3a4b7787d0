"""Ties in Table 1: cells with the same lowest dev loss are marked, and told apart by the train loss.

The shipped real sample (data/apollocar3d-sample) ties 5 of its 9 cells at dev loss 0; the pick was the
first tied cell in grid order and the table did not say that cells tied. Synthetic grids here.
"""
from __future__ import annotations

import pandas as pd
import pytest

from scenes import configuration_set
from sdm.errors import SDMInputError
from sdm.experiments import settings_for, tune_cell
from sdm.metrics import dev_loss
from sdm.experiments.report.tables import TABLE1_FORMAT, best_cell, best_index, lowest, table1_frame, to_latex, to_markdown, write_table


def grid(cells) -> pd.DataFrame:
    """``cells``: (n_epoch, lr, dev_loss, train_loss), in any order; distance made up (never read to choose)."""
    return pd.DataFrame([{"n_epoch": n, "lr": lr, "dev_loss": dev, "train_loss": train, "distance": 1e-3 * (9 - i)}
                         for i, (n, lr, dev, train) in enumerate(cells)])


TIED = grid([(32, 1e-3, 0.0, 0.0), (8, 1e-4, 11.5625, 11.9), (8, 1e-3, 0.0, 0.0244), (16, 3e-4, 0.0, 0.2195),
             (16, 1e-3, 0.0, 0.0), (8, 3e-4, 3.125, 1.68)])


def test_tied_cells_are_marked_and_the_train_loss_breaks_the_tie():
    """Four cells tie at 0: the first of them in grid order (8, 1e-3) loses to the lower train losses; of the two
    at train loss 0, the most epochs picks (32, 1e-3), not the least-trained (16, 1e-3)."""
    table = table1_frame(TIED.sample(frac=1, random_state=1))
    assert table.loc[table["best"], ["n_epoch", "lr"]].values.tolist() == [[32, 1e-3]]
    assert table.loc[table["tied"], ["n_epoch", "lr"]].values.tolist() == [[8, 1e-3], [16, 3e-4], [16, 1e-3],
                                                                            [32, 1e-3]]
    shown = dict(zip(zip(table["n_epoch"], table["lr"]), table["train_loss"]))
    assert shown == dict(zip(zip(TIED["n_epoch"], TIED["lr"]), TIED["train_loss"]))
    assert best_cell(TIED) == {"n_epoch": 32, "lr": 1e-3, "dev_loss": 0.0}


def test_the_tables_say_which_cells_tied_and_how_the_tie_was_broken(tmp_path):
    table = table1_frame(TIED)
    markdown, latex = to_markdown(table, TABLE1_FORMAT), to_latex(table, TABLE1_FORMAT)
    assert "tied (ours)" in markdown and "train loss (ours)" in markdown
    assert "| 32 | 1e-03 | 0.000 | - | yes |  |" in markdown  # best, then paper's best, ...
    assert markdown.count("| yes |") >= 4 and "lowest train loss" in markdown and "most epochs" in markdown
    assert "lowest train loss" in latex
    csv = write_table(table, tmp_path / "table1", TABLE1_FORMAT)[0]
    assert pd.read_csv(csv)["tied"].sum() == 4


def test_a_tie_free_table_has_no_tie_column_nor_note():
    """Without ties Table 1 keeps the columns and the notes it had before ties were marked (its files unchanged)."""
    free = grid([(1, 1e-4, 5.0, 4.0), (1, 3e-4, 0.8, 0.1), (2, 1e-4, 0.9, 0.0)])
    table = table1_frame(free)
    assert list(table.columns) == ["n_epoch", "lr", "dev_loss", "paper_dev_loss", "best", "paper_best", "distance_mm"]
    assert table.loc[table["best"], ["n_epoch", "lr"]].values.tolist() == [[1, 3e-4]]  # the train loss plays no part
    assert "tied" not in to_markdown(table, TABLE1_FORMAT) and "train loss" not in to_latex(table, TABLE1_FORMAT)


def test_tied_means_the_same_count_not_the_same_bits():
    """A dev loss is a count over n configurations: 3/16 read back with a last-bit error still ties with 3/16;
    one pixel more (4/16) or one in a million configurations more does not."""
    values = pd.Series([3 / 16, 3 / 16 + 2e-17, 3 / 16 * (1 + 1e-15), 4 / 16, 3 / 16 + 1e-6])
    assert lowest(values).tolist() == [True, True, True, False, False]
    assert lowest(pd.Series([0.0, 1 / 1_000_000, 0.0])).tolist() == [True, False, True]
    assert lowest(pd.Series([1000.0, 1000.0 + 1e-4])).tolist() == [True, False]


def test_ties_on_both_losses_go_to_the_most_epochs_then_the_smaller_lr():
    """Not the least-trained tied cell (the grid's first): the most epochs, then the smaller learning rate."""
    both = grid([(2, 1e-3, 0.5, 0.25), (1, 1e-3, 0.5, 0.25), (2, 3e-4, 0.5, 0.25), (1, 3e-4, 0.5, 0.25),
                 (4, 1e-4, 0.75, 0.0)])
    assert best_cell(both) == {"n_epoch": 2, "lr": 3e-4, "dev_loss": 0.5}
    assert best_cell(both.iloc[[1, 3]]) == {"n_epoch": 1, "lr": 3e-4, "dev_loss": 0.5}
    assert table1_frame(both)["tied"].sum() == 4


def test_a_tie_without_train_losses_is_refused_naming_the_column():
    """A grid of cells written before the tie-break (no train_loss) would silently fall back to grid order."""
    old = TIED.drop(columns="train_loss")
    with pytest.raises(SDMInputError, match="train_loss"):
        table1_frame(old)
    assert best_index(old.iloc[[1, 5]]) == 5  # no tie: no train loss needed


def test_tune_cell_records_the_train_loss_at_the_final_theta():
    data = configuration_set(48, seed=6)
    train_set, dev_set = data.subset(range(32)), data.subset(range(32, 48))
    record, _ = tune_cell(train_set, dev_set, settings_for(1, 3e-4, 4, 16, 0.5, 0))
    theta = (record["a"], record["b"])
    assert record["train_loss"] == dev_loss(train_set, theta, s=4)
    assert record["dev_loss"] == dev_loss(dev_set, theta, s=4) and record["train_loss"] != record["dev_loss"]



def test_the_reproduction_report_says_how_a_tied_pick_was_made(tmp_path):
    """The report (which reads table1.csv) shows the marked table, and its gap line names the tie and its break."""
    from test_report import CONFIG, distances

    from sdm.experiments.report.reproduction import build_report
    from sdm.experiments.report.tables import table2_frame

    runs = distances((0.77, 41.0, 25.0, 35.0, 40.0))
    paper_grid = grid([(1, 1e-4, 5.0, 4.0), (1, 3e-4, 0.8, 0.7), (1, 1e-3, 0.25, 0.5), (2, 1e-4, 0.25, 0.125),
                       (2, 3e-4, 0.25, 0.125), (2, 1e-3, 1.0, 1.0)])  # the paper's cells: its pick (1, 3e-4) loses
    table1 = pd.read_csv(write_table(table1_frame(paper_grid), tmp_path / "table1", TABLE1_FORMAT)[0])
    assert table1.loc[table1["best"], ["n_epoch", "lr"]].values.tolist() == [[2, 1e-4]]
    text = build_report(table1, table2_frame(runs, {}), runs, {"target_mean_depth": 50.0}, {}, CONFIG)
    assert "tied with 2 other cell(s), the lowest train loss among them (0.125; then the most epochs, the smaller lr)" in text
    assert "the lowest train loss, the dev loss's measure on the training configurations" in text

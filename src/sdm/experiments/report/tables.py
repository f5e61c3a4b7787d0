"""Tables 1 and 2 with the paper's values beside ours, and their CSV / Markdown / LaTeX writers.

Units: dev loss in pixels; distances in 1e-3 m (the paper's Table 2 unit); "Avg. Dist." in mm.
"""
from __future__ import annotations

import html
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from ...errors import SDMInputError
from .. import paper
from .io import write_csv, write_text

#: Statistics of Table 2, in the paper's order.
TABLE2_STATS = ("mean", "std", "q1", "q2", "q3")


# -- Table 1 ------------------------------------------------------------------------------------


def paper_table1_value(n_epoch: int, lr: float) -> float:
    """The paper's dev loss for a grid cell, NaN where the paper has no such cell."""
    for (n, rate), value in paper.TABLE1.items():
        if n == int(n_epoch) and math.isclose(rate, float(lr), rel_tol=1e-9):
            return value
    return math.nan


#: Two dev (or train) losses this close, relative to max(1, the lowest), are one value: "tied". Each loss is
#: an integer count of pixels over the number of configurations n, so two different counts differ by at
#: least 1/n (1e-6 for a million configurations), while the same count read back from a cell's JSON and
#: from grid.csv may differ in the last bit; exact float equality would make the tie depend on the file.
TIE_TOLERANCE = 1e-9


def lowest(values: pd.Series) -> pd.Series:
    """Which of ``values`` (counts over configurations, e.g. dev losses) tie with the lowest (:data:`TIE_TOLERANCE`)."""
    low = float(values.min())
    return (values.astype(float) - low).abs() <= TIE_TOLERANCE * max(1.0, abs(low))


def best_index(grid: pd.DataFrame):
    """The label of the best row of a tuning grid: the lowest ``dev_loss``; among cells tied on it, the
    lowest ``train_loss``; among cells tied on both, the most epochs (the most SGD steps), then the smaller
    learning rate.

    Why the train loss: it is the dev loss's own measure (false-positive pixels at zoom 0 at the cell's
    final theta) on the training configurations, more evidence about the same final theta from the
    other part of the data, and it needs no theta*. The alternatives were weaker: the mini-batch losses of
    the run's last steps are the loss along the way over part of the set, not at the final theta.
    Why the most-trained cell last (a choice, not a measurement): cells tied on both losses fit every dev and
    training configuration equally, so the data cannot tell them apart; the grid order used to pick the
    least-trained of them. More epochs at a smaller rate end on smaller steps (the rate halves per level),
    so the run has had the most chance to settle; it too needs no theta*.

    Raises:
        SDMInputError: cells tie on ``dev_loss`` and the grid has no ``train_loss`` column.
    """
    candidates = grid[lowest(grid["dev_loss"])]
    if len(candidates) > 1:
        if "train_loss" not in grid:
            raise SDMInputError(f"tuning grid: {len(candidates)} cells tie on the dev loss and the grid has no "
                                f"train_loss column to tell them apart (sdm.experiments.tune_cell writes it)")
        candidates = candidates[lowest(candidates["train_loss"])]
    # Stable sort: rows equal on both keys keep the grid's order.
    return candidates.sort_values(["n_epoch", "lr"], ascending=[False, True], kind="stable").index[0]


def table1_frame(grid: pd.DataFrame) -> pd.DataFrame:
    """Table 1: our dev loss per grid cell beside the paper's.

    Args:
        grid: one row per cell with columns ``n_epoch``, ``lr``, ``dev_loss`` (and optionally
            ``train_loss``, the tie-break, and ``distance``, metres, of the cell's final theta).

    Returns:
        Columns ``n_epoch, lr, dev_loss, paper_dev_loss, best, paper_best`` (+ ``distance_mm``),
        sorted by ``n_epoch`` then ``lr``; ``best`` marks our pick (:func:`best_index`). Only when
        cells tie on the lowest dev loss, also ``tied`` (those cells) and ``train_loss``: a
        tie-free table is what it was before ties were marked.
    """
    require_columns(grid, ("n_epoch", "lr", "dev_loss"), "tuning grid")
    if grid.empty:
        raise SDMInputError("tuning grid: no cell")
    frame = grid.sort_values(["n_epoch", "lr"]).reset_index(drop=True)
    out = pd.DataFrame(
        {
            "n_epoch": frame["n_epoch"].astype(int),
            "lr": frame["lr"].astype(float),
            "dev_loss": frame["dev_loss"].astype(float),
        }
    )
    out["paper_dev_loss"] = [paper_table1_value(n, lr) for n, lr in zip(out["n_epoch"], out["lr"])]
    train_loss = frame["train_loss"].astype(float) if "train_loss" in frame else None
    out["best"] = False
    out.loc[best_index(out if train_loss is None else out.assign(train_loss=train_loss)), "best"] = True
    best_n, best_lr = paper.TABLE1_BEST
    out["paper_best"] = [(n == best_n and math.isclose(lr, best_lr)) for n, lr in zip(out["n_epoch"], out["lr"])]
    if "distance" in frame:
        out["distance_mm"] = 1000.0 * frame["distance"].astype(float)
    tied = lowest(out["dev_loss"])
    if tied.sum() > 1:  # only then: a tie-free table keeps its columns (and its files their bytes)
        out["tied"] = tied
        out["train_loss"] = train_loss
    return out


def best_cell(grid: pd.DataFrame) -> dict:
    """The grid cell Table 1 marks best (:func:`best_index`: the lowest dev loss, ties broken by the train loss)."""
    table = table1_frame(grid)
    row = table[table["best"]].iloc[0]
    return {"n_epoch": int(row["n_epoch"]), "lr": float(row["lr"]), "dev_loss": float(row["dev_loss"])}


# -- Table 2 ------------------------------------------------------------------------------------


def table2_frame(distances: pd.DataFrame, avg_dist_mm: dict[int, float]) -> pd.DataFrame:
    """Table 2: statistics of the distances per noise level beside the paper's.

    Args:
        distances: one row per run with columns ``noise_level`` and ``distance`` (metres).
        avg_dist_mm: "Avg. Dist." in mm per noise level (from the data's mean target depth;
            :func:`sdm.experiments.data.stats.avg_dist_mm`); level 0 may be missing (it is 0).

    Returns:
        One row per level: ``noise_level, runs, avg_dist_mm, paper_avg_dist_mm``, then for each of
        ``mean, std, q1, q2, q3`` our value and ``paper_<stat>`` (1e-3 m), and ``mean_ratio``
        (ours / paper). ``std`` is the sample standard deviation; quartiles interpolate linearly.
    """
    require_columns(distances, ("noise_level", "distance"), "noise distances")
    if distances.empty:
        raise SDMInputError("noise distances: no run")
    rows = []
    for noise_level, group in distances.groupby("noise_level", sort=True):
        values = 1000.0 * group["distance"].to_numpy(dtype=float)
        theirs = paper.TABLE2.get(int(noise_level), {})
        row = {
            "noise_level": int(noise_level),
            "runs": int(values.size),
            "avg_dist_mm": 0.0 if int(noise_level) == 0 else float(avg_dist_mm.get(int(noise_level), math.nan)),
            "paper_avg_dist_mm": theirs.get("avg_dist", math.nan),
        }
        ours = {
            "mean": float(values.mean()),
            "std": float(values.std(ddof=1)) if values.size > 1 else math.nan,
            "q1": float(np.quantile(values, 0.25)),
            "q2": float(np.quantile(values, 0.5)),
            "q3": float(np.quantile(values, 0.75)),
        }
        for stat in TABLE2_STATS:
            row[stat] = ours[stat]
            row[f"paper_{stat}"] = theirs.get(stat, math.nan)
        row["mean_ratio"] = ours["mean"] / theirs["mean"] if theirs else math.nan
        rows.append(row)
    return pd.DataFrame.from_records(rows)


# -- presentation -------------------------------------------------------------------------------


@dataclass
class TableFormat:
    """How a table frame is shown in Markdown and LaTeX.

    Attributes:
        columns: frame columns to show, in order.
        headers: column -> header text (default: the column name).
        formats: column -> ``str.format`` spec such as ``".3f"`` (default: ``str``).
        caption: caption (LaTeX) / title line (Markdown).
        label: LaTeX label.
        notes: lines printed under the table.
        column_notes: column -> a line printed under the table only when the frame has that column.
    """

    columns: Sequence[str]
    headers: dict[str, str] = field(default_factory=dict)
    formats: dict[str, str] = field(default_factory=dict)
    caption: str = ""
    label: str = ""
    notes: Sequence[str] = ()
    column_notes: dict[str, str] = field(default_factory=dict)

    def notes_for(self, frame: pd.DataFrame) -> list[str]:
        """The lines under ``frame``'s table: :attr:`notes`, then the notes of the columns it has."""
        return list(self.notes) + [note for column, note in self.column_notes.items() if column in frame]

    def cell(self, column: str, value) -> str:
        if isinstance(value, (bool, np.bool_)):
            return "yes" if value else ""
        if isinstance(value, (float, np.floating)) and math.isnan(value):
            return "-"
        spec = self.formats.get(column)
        return format(value, spec) if spec else str(value)


TABLE1_FORMAT = TableFormat(
    columns=("n_epoch", "lr", "dev_loss", "paper_dev_loss", "best", "paper_best", "distance_mm", "tied", "train_loss"),
    headers={
        "n_epoch": "n_epoch",
        "lr": "learning rate",
        "dev_loss": "dev loss (ours)",
        "paper_dev_loss": "dev loss (paper)",
        "best": "best (ours)",
        "paper_best": "best (paper)",
        "distance_mm": "distance (ours, 1e-3 m)",
        "tied": "tied (ours)",
        "train_loss": "train loss (ours)",
    },
    formats={"lr": ".0e", "dev_loss": ".3f", "paper_dev_loss": ".3f", "distance_mm": ".3f", "train_loss": ".3f"},
    caption="Table 1: dev loss (mean false-positive pixels per dev configuration) over the tuning grid",
    label="tab:table1",
    notes=("The distance column is ||theta~ - theta*|| of the cell's run (no counterpart in the paper).",),
    column_notes={"tied": (
        "Tied: the cell's dev loss equals the lowest (the same count of pixels). Among tied cells the best is "
        "the one with the lowest train loss, the dev loss's measure on the training configurations at the "
        "cell's final theta; among cells tied on that too, the most epochs (SGD steps), then the smaller "
        "learning rate. None of these uses theta*."
    )},
)

TABLE2_FORMAT = TableFormat(
    columns=(
        "noise_level", "runs", "avg_dist_mm", "paper_avg_dist_mm",
        "mean", "paper_mean", "std", "paper_std", "q1", "paper_q1", "q2", "paper_q2", "q3", "paper_q3",
    ),
    headers={
        "noise_level": "noise level",
        "runs": "runs",
        "avg_dist_mm": "Avg. Dist. (ours)",
        "paper_avg_dist_mm": "Avg. Dist. (paper)",
        "mean": "mean", "paper_mean": "mean (paper)",
        "std": "std", "paper_std": "std (paper)",
        "q1": "Q1", "paper_q1": "Q1 (paper)",
        "q2": "Q2", "paper_q2": "Q2 (paper)",
        "q3": "Q3", "paper_q3": "Q3 (paper)",
    },
    formats={"avg_dist_mm": ".1f", "paper_avg_dist_mm": ".1f"}
    | {c: ".3f" for c in ("mean", "std", "q1", "q2", "q3")}
    | {f"paper_{c}": ".3f" for c in ("mean", "std", "q1", "q2", "q3")},
    caption="Table 2: distance ||theta~ - theta*|| per noise level (1e-3 m; Avg. Dist. in mm)",
    label="tab:table2",
)


def to_markdown(frame: pd.DataFrame, style: TableFormat) -> str:
    """A GitHub-flavoured Markdown table (title line, table, notes)."""
    columns = [c for c in style.columns if c in frame]
    numeric = {c: pd.api.types.is_numeric_dtype(frame[c]) and not pd.api.types.is_bool_dtype(frame[c]) for c in columns}
    lines = [f"**{_md_inline(style.caption)}**", ""] if style.caption else []
    lines.append("| " + " | ".join(_md_escape(style.headers.get(c, c)) for c in columns) + " |")
    lines.append("|" + "|".join("---:" if numeric[c] else ":---:" for c in columns) + "|")
    for row in _rows(frame, columns):
        lines.append("| " + " | ".join(_md_escape(style.cell(c, v)) for c, v in zip(columns, row)) + " |")
    notes = style.notes_for(frame)
    if notes:
        lines += [""] + notes
    return "\n".join(lines) + "\n"


def to_latex(frame: pd.DataFrame, style: TableFormat) -> str:
    """A LaTeX ``table`` with a ``tabular`` (no package beyond LaTeX itself)."""
    columns = [c for c in style.columns if c in frame]
    lines = [
        r"\begin{table}[htbp]",
        r"\centering",
        rf"\caption{{{_tex_escape(style.caption)}}}" if style.caption else "",
        rf"\label{{{style.label}}}" if style.label else "",
        r"\begin{tabular}{|" + "|".join("c" for _ in columns) + "|}",
        r"\hline",
        " & ".join(_tex_escape(style.headers.get(c, c)) for c in columns) + r" \\",
        r"\hline",
    ]
    for row in _rows(frame, columns):
        lines.append(" & ".join(_tex_escape(style.cell(c, v)) for c, v in zip(columns, row)) + r" \\")
    lines += [r"\hline", r"\end{tabular}"]
    lines += [rf"\par\smallskip {{\footnotesize {_tex_escape(note)}}}" for note in style.notes_for(frame)]
    lines.append(r"\end{table}")
    return "\n".join(line for line in lines if line) + "\n"


def write_table(frame: pd.DataFrame, stem: str | Path, style: TableFormat,
                shown: pd.DataFrame | None = None) -> list[Path]:
    """Write ``stem.csv`` (``frame``, full precision), ``stem.md``, ``stem.tex`` and ``stem.html`` (the
    Markdown as a page, :func:`markdown_page`), each atomically.

    ``shown`` is what the Markdown and LaTeX render (default ``frame`` itself), e.g. ``frame``
    with its metres in 1e-3 m (:func:`in_millimetres`) while the CSV keeps metres.
    """
    stem = Path(stem)
    shown = frame if shown is None else shown
    markdown = to_markdown(shown, style)
    return [
        write_csv(stem.with_suffix(".csv"), frame),
        write_text(stem.with_suffix(".md"), markdown),
        write_text(stem.with_suffix(".tex"), to_latex(shown, style)),
        write_text(stem.with_suffix(".html"), markdown_page(markdown, style.caption)),
    ]


def markdown_page(markdown: str, title: str) -> str:
    """Markdown (a table with its caption and notes, or a report) as a standalone HTML page.

    ``snakemake --report`` shows images, HTML and PDF in the page and offers any other file (a CSV, a
    Markdown file) as a download only, so the tables and the report are flagged for it as these pages.
    Rendered by mistune (what nbconvert renders notebooks' Markdown with), tables included.
    """

    import mistune

    style = ("body{font-family:sans-serif;margin:1.5em;color:#222}table{border-collapse:collapse;font-size:90%}"
             "th,td{border:1px solid #bbb;padding:3px 7px;text-align:right}th{background:#eee}")
    return (f'<!doctype html>\n<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>'
            f"<style>{style}</style></head><body>\n{mistune.html(markdown)}</body></html>\n")


def in_millimetres(frame: pd.DataFrame, names: Sequence[str]) -> pd.DataFrame:
    """A copy of ``frame`` with column ``name`` = 1e3 x ``name_m`` (metres to 1e-3 m) for each of ``names``
    whose ``name_m`` column is present."""
    shown = frame.copy()
    for name in names:
        if f"{name}_m" in frame:
            shown[name] = 1e3 * frame[f"{name}_m"]
    return shown


def _rows(frame: pd.DataFrame, columns: Sequence[str]):
    """Rows as tuples of Python values, each column keeping its own type (iterrows would upcast ints)."""
    return zip(*(frame[c].tolist() for c in columns))


def require_columns(frame: pd.DataFrame, columns: Sequence[str], what: str, *, runs: bool = False) -> None:
    """:class:`SDMInputError` naming ``what`` where ``frame`` lacks one of ``columns``; with ``runs``, also where it
    holds no row (a table of runs without a run)."""
    missing = [c for c in columns if c not in frame]
    if missing:
        raise SDMInputError(f"{what}: missing column(s) {missing}; has {list(frame.columns)}")
    if runs and frame.empty:
        raise SDMInputError(f"{what}: no run")


def _md_escape(text: str) -> str:
    return str(text).replace("|", r"\|")


#: Characters that open or close Markdown emphasis, code or links: in a bold title, ``theta*`` would close the
#: bold early and ``theta~`` could open a strikethrough.
_MD_INLINE = re.compile(r"([\\`*_~\[\]<>])")


def _md_inline(text: str) -> str:
    """``text`` as literal Markdown inline text: each emphasis, code or link character backslash-escaped."""
    return _MD_INLINE.sub(r"\\\1", str(text))


_TEX_SPECIAL = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
                "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}


def _tex_escape(text: str) -> str:
    return "".join(_TEX_SPECIAL.get(ch, ch) for ch in str(text))

"""Table 5: the shift with depth, ``theta = (a, b, c)`` (beyond the paper; docs/method/depth.md).

Table 5 gives, per true depth shift ``c*`` and noise level, the mean absolute errors of ``a``, ``b`` and ``c`` and
the distance to ``theta* = (a*, b*, c*)``, against the depth bar for the noise-free runs (``a``, ``b`` within 2e-3 m
and ``c`` within 2e-2 m, mean over the runs).

Units: the CSV keeps metres (``*_m``); the Markdown and LaTeX tables show 1e-3 m, like Table 2.
"""
from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from .tables import TableFormat, in_millimetres, require_columns, write_table

#: The depth bar for the noise-free runs (metres): mean |a - a*|, |b - b*| and |c - c*|.
DEPTH_BAR_M = {"a": 2e-3, "b": 2e-3, "c": 2e-2}

#: Per-run columns Table 5 needs (``sdm.experiments.DEPTH_RUN_COLUMNS``).
DEPTH_RUN_COLUMNS = ("c_true", "noise_level", "run", "c", "error_a", "error_b", "error_c", "distance_ab", "distance")



def table5_frame(depth_runs: pd.DataFrame) -> pd.DataFrame:
    """Table 5: the shift with depth, per true ``c*`` and noise level.

    Args:
        depth_runs: one row per (c_true, noise_level, run) with :data:`DEPTH_RUN_COLUMNS` (metres).

    Returns:
        One row per (c_true, level), sorted: ``c_true, level, runs``; the means over the runs of
        ``error_a_m, error_b_m, error_c_m`` (absolute errors), ``bias_c_m`` (the signed mean of ``c - c*``: positive
        is too far), ``distance_ab_m`` and ``distance_m``
        (to ``(a*, b*)`` and to ``(a*, b*, c*)``), ``distance_std_m``; ``meets_bar`` (noise-free
        rows only, :data:`DEPTH_BAR_M`; ``False`` at noisy levels, where none is set).
    """
    require_columns(depth_runs, DEPTH_RUN_COLUMNS, "Table 5 depth runs", runs=True)
    rows = []
    for (c_true, noise_level), group in depth_runs.groupby(["c_true", "noise_level"], sort=True):
        row = {"c_true": float(c_true), "noise_level": int(noise_level), "runs": int(len(group))}
        for column in ("error_a", "error_b", "error_c", "distance_ab", "distance"):
            row[f"{column}_m"] = float(group[column].mean())
        row["bias_c_m"] = float((group["c"] - group["c_true"]).mean())
        row["distance_std_m"] = float(group["distance"].std(ddof=1)) if len(group) > 1 else math.nan
        row["meets_bar"] = bool(int(noise_level) == 0 and all(row[f"error_{axis}_m"] <= bar for axis, bar in DEPTH_BAR_M.items()))
        rows.append(row)
    return pd.DataFrame.from_records(rows)


_TABLE5_DISTANCES = ("error_a", "error_b", "error_c", "bias_c", "distance_ab", "distance", "distance_std")

TABLE5_FORMAT = TableFormat(
    columns=("c_true", "noise_level", "runs", "error_a", "error_b", "error_c", "bias_c", "distance_ab", "distance",
             "distance_std", "meets_bar"),
    headers={
        "c_true": "c* (m)", "noise_level": "noise level", "runs": "runs", "error_a": "|a - a*|", "error_b": "|b - b*|",
        "error_c": "|c - c*|", "bias_c": "mean c - c*", "distance_ab": "distance in (a, b)",
        "distance": "distance in (a, b, c)", "distance_std": "std of distance", "meets_bar": "meets bar (noise-free)",
    },
    formats={"c_true": "g"} | {c: ".3f" for c in _TABLE5_DISTANCES},
    caption="Table 5: the shift (a, b, c) with depth, mean absolute errors per true c* and noise level (1e-3 m)",
    label="tab:table5",
    notes=(
        "theta* = (a*, b*, c*); the training set's targets rebuilt for its points moved by theta*; run r at level n "
        "draws the noise and shuffling of Table 2's run r; (a, b, c) trained from (0, 0, 0) with fit_depth. "
        "bar (noise-free): mean |a - a*| and |b - b*| at most 2 (1e-3 m), |c - c*| at most 20.",
    ),
)


def table5_display(frame: pd.DataFrame) -> pd.DataFrame:
    """Table 5 for Markdown / LaTeX: errors in 1e-3 m under the short names of :data:`TABLE5_FORMAT`."""
    return in_millimetres(frame, _TABLE5_DISTANCES)


def table5_summary(frame: pd.DataFrame) -> str:
    """Table 5 in plain words (Markdown): the noise-free rows against the depth bar, then the noisy levels."""
    lines = []
    for c_true, rows in frame.groupby("c_true", sort=True):
        parts = []
        for row in rows.sort_values("noise_level").itertuples():
            errors = (f"|a - a*| {1e3 * row.error_a_m:.3f}, |b - b*| {1e3 * row.error_b_m:.3f}, "
                      f"|c - c*| {1e3 * row.error_c_m:.3f}")
            if row.noise_level == 0:
                verdict = "meets" if row.meets_bar else "misses"
                parts.append(f"noise-free {errors} ({verdict} the bar of 2, 2 and 20)")
            else:
                parts.append(f"level {row.noise_level} {errors}")
        runs = ", ".join(sorted({str(int(r)) for r in rows["runs"]}))
        lines.append(f"- c* = {c_true:g} m ({runs} runs per level), mean errors in 1e-3 m: " + "; ".join(parts) + ".")
    if not (frame["noise_level"] == 0).any():
        lines.append("- No noise-free level was run: the depth bar was not checked.")
    return "\n".join(lines) + "\n"


def table5_bias_summary(frame: pd.DataFrame, bias: pd.DataFrame) -> str:
    """Why ``c`` is biased, in plain words (Markdown): Table 5's signed mean ``c - c*`` beside what
    :func:`sdm.experiments.depth_bias` measured at theta* (one row per ``rule``, ``c_true``, ``noise_level``, ``zoom``).

    Per c* and noisy level: the measured bias, then each measured rule's predicted fixed point of ``c`` and the
    share of its depth flow that comes from the points at the edges of the discs, with how often those land on
    empty blocks against the other points.
    """
    lines = []
    measured = {(float(row.c_true), int(row.noise_level)): row.bias_c_m for row in frame.itertuples()}
    for (c_true, noise_level), rows in bias[bias["noise_level"] > 0].groupby(["c_true", "noise_level"], sort=True):
        parts = [f"{row.rule} at zoom {int(row.zoom)}: predicted {1e3 * row.offset_c:+.2f}, "
                 f"{100 * row.edge_share:.0f}% of its pull from disc edges (their points on empty blocks "
                 f"{100 * row.unmatched_edge:.1f}%, the others {100 * row.unmatched_inside:.1f}%)"
                 for row in rows.itertuples()]
        runs = measured.get((float(c_true), int(noise_level)))
        head = f"mean c - c* {1e3 * runs:+.2f}" if runs is not None else "no runs"
        lines.append(f"- c* = {c_true:g} m, level {int(noise_level)} (1e-3 m): {head}; " + "; ".join(parts) + ".")
    return "\n".join(lines) + "\n" if lines else ""


def write_table5(frame: pd.DataFrame, stem: str | Path) -> list[Path]:
    """``stem.csv`` (metres, full precision), ``stem.md``, ``stem.tex`` and ``stem.html`` (1e-3 m) of Table 5,
    atomically."""
    return write_table(frame, stem, TABLE5_FORMAT, table5_display(frame))


def depth_figure(frame: pd.DataFrame):
    """Mean absolute errors of a, b (1e-3 m) and c (1e-2 m) per noise level, one line per true c*.

    Args:
        frame: :func:`table5_frame`.

    Returns:
        A matplotlib figure with three panels, the noise-free depth bar dashed.
    """
    from .figures import plt

    fig, axes = plt.subplots(1, 3, figsize=(13.5, 4.2), constrained_layout=True)
    colours = plt.get_cmap("tab10")
    for ax, (axis, scale, unit) in zip(axes, (("a", 1e3, "1e-3 m"), ("b", 1e3, "1e-3 m"), ("c", 1e2, "1e-2 m"))):
        for i, (c_true, rows) in enumerate(frame.groupby("c_true", sort=True)):
            rows = rows.sort_values("noise_level")
            ax.plot(rows["noise_level"], scale * rows[f"error_{axis}_m"], marker="o", color=colours(i), label=f"c* = {c_true:g} m")
        ax.axhline(scale * DEPTH_BAR_M[axis], ls="--", color="grey", lw=0.8, label="bar (noise-free)")
        ax.set_yscale("log")
        ax.set_xticks(sorted(frame["noise_level"].unique()))
        ax.set_xlabel("noise level n (pixels)")
        ax.set_ylabel(f"mean |{axis} - {axis}*| ({unit})")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle("Table 5: the shift (a, b, c) with depth", fontsize=11)
    return fig

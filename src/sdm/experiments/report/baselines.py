"""Table 3 (SDM against the baselines, paired runs per noise level) and its figure.

Units: the CSV keeps metres (``*_m``) and seconds; the Markdown and LaTeX tables show distances in
1e-3 m like Table 2. The paper has no Table 3: its SDM figures (Table 2's mean, std and median) sit
beside our SDM rows only.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from ...errors import SDMInputError
from ...sky import SKY_SHIFT
from .. import paper
from .tables import TableFormat, in_millimetres, require_columns, write_table

#: The per-run columns Table 3 needs (``sdm.experiments.baselines.RUN_COLUMNS`` has these and more).
RUN_COLUMNS = ("method", "noise_level", "run", "a", "b", "distance", "seconds")

#: Display order and labels (the registry's order; unknown methods go last under their own name).
METHOD_LABELS = {
    "sdm": "SDM",
    "silhouette": "soft silhouette",
    "chamfer": "2D Chamfer",
    "sinkhorn": "Sinkhorn OT",
    "cmaes": "CMA-ES (pixels)",
    "floor": "floor (exact-mismatch minimiser)",
}
#: The floor's rows (:mod:`sdm.experiments.baselines.floor`): what every method is read against, not a competitor.
FLOOR = "floor"
#: Per-run columns the floor's summary needs (``sdm.experiments.baselines.floor.FLOOR_COLUMNS`` has these and more).
FLOOR_RUN_COLUMNS = ("noise_level", "run", "a", "b", "distance", "search_distance", "half_distance", "extent_a",
                     "extent_b", "min_mismatch", "mismatch_at_truth", "seconds")


def _order(methods: Sequence[str]) -> list[str]:
    known = [m for m in METHOD_LABELS if m in set(methods)]
    return known + sorted(set(methods) - set(known))


def table3_frame(runs: pd.DataFrame, shift: Sequence[float] = SKY_SHIFT, reference: str = "sdm") -> pd.DataFrame:
    """Table 3: per method and noise level, the distances' statistics, time per run, and the pairing with SDM.

    Args:
        runs: one row per (method, noise_level, run) with :data:`RUN_COLUMNS` (metres, seconds).
        shift: theta* (metres).
        reference: the method the others are paired with (same level and run = same noisy targets).

    Returns:
        One row per (method, level): ``method, label, level, runs``; ``mean_m, std_m, median_m,
        q1_m, q3_m`` of ``||theta~ - theta*||``; ``bias_m`` (distance from the mean theta~ to
        theta*) and ``spread_m`` (root mean square distance of the theta~ to their mean; so
        ``mean squared distance = bias^2 + spread^2``); ``seconds_per_run`` (mean); ``paper_mean_m,
        paper_std_m, paper_median_m`` (Table 2's, SDM rows only); ``mean_ratio_to_sdm`` and
        ``wins_vs_sdm`` (share of paired runs with a smaller distance than the reference's, ties
        count half), NaN where the reference has no such run.
    """
    require_columns(runs, RUN_COLUMNS, "Table 3 runs", runs=True)
    duplicated = runs.duplicated(["method", "noise_level", "run"])
    if duplicated.any():
        first = runs[duplicated].iloc[0]
        raise SDMInputError(f"Table 3 runs: (method, noise_level, run) = ({first['method']}, {first['noise_level']}, {first['run']}) twice")
    a_star, b_star = (float(v) for v in shift)
    base = runs[runs["method"] == reference].set_index(["noise_level", "run"])["distance"]
    rows = []
    for name in _order(runs["method"].unique()):
        for noise_level, group in runs[runs["method"] == name].groupby("noise_level", sort=True):
            values = group["distance"].to_numpy(dtype=float)
            a, b = group["a"].to_numpy(dtype=float), group["b"].to_numpy(dtype=float)
            mean_a, mean_b = a.mean(), b.mean()
            theirs = paper.TABLE2.get(int(noise_level), {}) if name == reference else {}
            row = {
                "method": name,
                "label": METHOD_LABELS.get(name, name),
                "noise_level": int(noise_level),
                "runs": int(values.size),
                "mean_m": float(values.mean()),
                "std_m": float(values.std(ddof=1)) if values.size > 1 else math.nan,
                "median_m": float(np.median(values)),
                "q1_m": float(np.quantile(values, 0.25)),
                "q3_m": float(np.quantile(values, 0.75)),
                "bias_m": math.hypot(mean_a - a_star, mean_b - b_star),
                "spread_m": float(np.sqrt(((a - mean_a) ** 2 + (b - mean_b) ** 2).mean())),
                "seconds_per_run": float(group["seconds"].mean()),
                "paper_mean_m": 1e-3 * theirs["mean"] if theirs else math.nan,
                "paper_std_m": 1e-3 * theirs["std"] if theirs else math.nan,
                "paper_median_m": 1e-3 * theirs["q2"] if theirs else math.nan,
            }
            paired = group.set_index(["noise_level", "run"])["distance"]
            common = paired.index.intersection(base.index)
            if len(common):
                ours, ref = paired.loc[common].to_numpy(float), base.loc[common].to_numpy(float)
                row["mean_ratio_to_sdm"] = float(ours.mean() / ref.mean()) if ref.mean() > 0 else math.nan
                row["wins_vs_sdm"] = float(((ours < ref) + 0.5 * (ours == ref)).mean())
            else:
                row["mean_ratio_to_sdm"] = row["wins_vs_sdm"] = math.nan
            rows.append(row)
    return pd.DataFrame.from_records(rows)


def table2_runs(distances: pd.DataFrame, timings: Sequence[Mapping], noise_levels: Sequence[int],
                runs: Sequence[int], name: str = "sdm") -> pd.DataFrame:
    """SDM's rows of Table 3: Table 2's runs themselves, with the time per run the noise stage measured.

    Table 2's run ``r`` at level ``n`` trains SDM on the noisy targets of ``run_seed(seed, n, r)``, the
    draw every baseline's run ``(n, r)`` sees too, so these rows pair with the baselines' by
    construction (``tests/baselines/test_baselines.py`` holds ``fit("sdm")`` on a run's targets to
    :func:`sdm.experiments.noise_runs`); nothing is trained again.

    Args:
        distances: Table 2's per-run rows (``noise_level, run, a, b, distance``; metres), e.g.
            ``results/noise/distances.csv``.
        timings: the noise jobs' records, one per chunk: ``{"noise_level", "runs", "seconds"}`` (wall seconds
            of the chunk's runs, trained together as one program). May be empty.
        levels, runs: the noise levels and run indices wanted (Table 3's).
        name: the method name the rows get.

    Returns:
        One row per wanted ``(noise_level, run)`` with :data:`RUN_COLUMNS`; ``seconds`` is the level's
        chunk seconds over its runs (NaN for a level with no timing record).

    Raises:
        SDMInputError: a wanted ``(noise_level, run)`` that Table 2 does not have.
    """
    require_columns(distances, [c for c in RUN_COLUMNS if c not in ("method", "seconds")], "Table 2's runs")
    wanted = pd.MultiIndex.from_product([[int(v) for v in noise_levels], [int(v) for v in runs]], names=["noise_level", "run"])
    table2 = distances.set_index(["noise_level", "run"])
    absent = wanted.difference(table2.index)
    if len(absent):
        noise_level, run = absent[0]
        raise SDMInputError(f"Table 2 has no run {run} at noise level {noise_level} ({len(absent)} of Table 3's runs "
                            f"missing): config key 'baselines.runs' must not exceed noise.runs")
    rows = table2.loc[wanted].reset_index()
    seconds, counted = {}, {}
    for record in timings:
        noise_level = int(record["noise_level"])
        seconds[noise_level] = seconds.get(noise_level, 0.0) + float(record["seconds"])
        counted[noise_level] = counted.get(noise_level, 0) + int(record["runs"])
    per_run = {noise_level: seconds[noise_level] / counted[noise_level] for noise_level in seconds if counted[noise_level] > 0}
    rows["seconds"] = [per_run.get(int(noise_level), math.nan) for noise_level in rows["noise_level"]]
    rows.insert(0, "method", name)
    return rows


#: Distance columns shown in 1e-3 m in the Markdown and LaTeX tables.
_DISTANCES = ("mean", "std", "median", "bias", "spread")

TABLE3_FORMAT = TableFormat(
    columns=(
        "label", "noise_level", "runs", "mean", "paper_mean", "std", "paper_std", "median", "paper_median",
        "bias", "spread", "seconds_per_run", "mean_ratio_to_sdm", "wins_vs_sdm",
    ),
    headers={
        "label": "method", "noise_level": "noise level", "runs": "runs",
        "mean": "mean", "paper_mean": "mean (paper)", "std": "std", "paper_std": "std (paper)",
        "median": "median", "paper_median": "median (paper)", "bias": "bias", "spread": "spread",
        "seconds_per_run": "s / run", "mean_ratio_to_sdm": "mean / SDM's", "wins_vs_sdm": "beats SDM",
    },
    formats={c: ".3f" for c in ("mean", "paper_mean", "std", "paper_std", "median", "paper_median", "bias", "spread")}
    | {"seconds_per_run": ".2f", "mean_ratio_to_sdm": ".2f", "wins_vs_sdm": ".0%"},
    caption="Table 3: distance ||theta~ - theta*|| per method and noise level (1e-3 m), paired runs",
    label="tab:table3",
    notes=(
        "Same training configurations and, per (noise_level, run), the same noisy targets for every method. "
        "bias: distance from the mean theta~ to theta*; spread: RMS distance of the theta~ to their mean. "
        "beats SDM: share of paired runs closer to theta* than SDM's (ties half). The paper reports SDM only.",
    ),
)


def table3_display(frame: pd.DataFrame) -> pd.DataFrame:
    """Table 3 for Markdown / LaTeX: distances in 1e-3 m under short names (``mean``, ``paper_mean``, ...)."""
    return in_millimetres(frame, [*_DISTANCES, *(f"paper_{stat}" for stat in _DISTANCES)])


def write_table3(frame: pd.DataFrame, stem: str | Path) -> list[Path]:
    """``stem.csv`` (metres, full precision), ``stem.md`` and ``stem.tex`` (1e-3 m), each atomically."""
    return write_table(frame, stem, TABLE3_FORMAT, table3_display(frame))


def tuning_frame(tunings: Sequence[pd.DataFrame]) -> pd.DataFrame:
    """The baselines' tuning grids side by side (like Table 1): ``method, cell, settings, dev_loss, distance_mm, seconds, best``.

    ``settings`` is the cell's varied fields as ``name=value`` text (fields equal in every cell of a
    method are left out).
    """
    rows = []
    for tuning in tunings:
        if tuning.empty:
            continue
        skip = {"method", "cell", "dev_loss", "a", "b", "distance", "seconds", "evaluations", "best"}
        varied = [c for c in tuning.columns if c not in skip and tuning[c].nunique(dropna=False) > 1]
        for _, row in tuning.iterrows():
            rows.append({
                "method": row["method"],
                "label": METHOD_LABELS.get(row["method"], row["method"]),
                "cell": int(row["cell"]),
                "settings": ", ".join(f"{c}={row[c]:g}" if isinstance(row[c], (int, float, np.number))
                                      and not isinstance(row[c], bool) else f"{c}={row[c]}" for c in varied) or "-",
                "dev_loss": float(row["dev_loss"]),
                "distance_mm": 1000.0 * float(row["distance"]),
                "seconds": float(row["seconds"]),
                "best": bool(row["best"]),
            })
    return pd.DataFrame.from_records(rows)


TUNING_FORMAT = TableFormat(
    columns=("label", "settings", "dev_loss", "distance_mm", "seconds", "best"),
    headers={"label": "method", "settings": "cell", "dev_loss": "dev loss", "distance_mm": "distance (1e-3 m)",
             "seconds": "seconds", "best": "chosen"},
    formats={"dev_loss": ".3f", "distance_mm": ".3f", "seconds": ".2f"},
    caption="Baseline tuning (like Table 1): dev loss (mean false-positive pixels per dev configuration) per cell",
    label="tab:table3-tuning",
    notes=("Each method's cell with the lowest dev loss is used for Table 3; the distance is shown, not used to choose.",),
)


# -- figure -----------------------------------------------------------------------------------------


def baselines_figure(table: pd.DataFrame, runs: pd.DataFrame | None = None, shift: Sequence[float] = SKY_SHIFT):
    """Distance against noise level per method (log scale), bias against spread, and where theta~ lands.

    Args:
        table: :func:`table3_frame`.
        runs: the per-run rows (for the third panel: theta~ - theta* at the noisiest level); optional.

    Returns:
        A matplotlib figure with two panels (three with ``runs``).
    """
    from .figures import plt  # the report's matplotlib, already on the Agg backend

    panels = 3 if runs is not None else 2
    fig, axes = plt.subplots(1, panels, figsize=(5.2 * panels, 4.4), constrained_layout=True)
    colours = plt.get_cmap("tab10")
    methods = _order(table["method"].unique())
    markers = dict(zip(methods, "osD^vP*X"))
    ax = axes[0]
    for i, name in enumerate(methods):
        rows = table[table["method"] == name].sort_values("noise_level")
        mm = 1000.0
        ax.errorbar(rows["noise_level"] + 0.06 * (i - len(methods) / 2), mm * rows["median_m"],
                    yerr=[mm * (rows["median_m"] - rows["q1_m"]), mm * (rows["q3_m"] - rows["median_m"])],
                    marker=markers[name], color=colours(i), capsize=3, label=METHOD_LABELS.get(name, name))
        if name == "sdm" and rows["paper_median_m"].notna().any():
            ax.plot(rows["noise_level"], mm * rows["paper_median_m"], ls=":", color=colours(i), label="SDM (paper)")
    ax.set_yscale("log")
    ax.set_xlabel("noise level n (pixels)")
    ax.set_ylabel("||theta~ - theta*|| (1e-3 m): median, Q1-Q3")
    ax.set_title("(a) distance per noise level", fontsize=10)
    ax.set_xticks(sorted(table["noise_level"].unique()))
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)

    ax = axes[1]
    for i, name in enumerate(methods):
        rows = table[table["method"] == name].sort_values("noise_level")
        ax.plot(1000 * rows["bias_m"].clip(lower=1e-6), 1000 * rows["spread_m"].clip(lower=1e-6),
                marker=markers[name], color=colours(i), label=METHOD_LABELS.get(name, name))
        for _, row in rows.iterrows():
            ax.annotate(str(int(row["noise_level"])), (1000 * max(row["bias_m"], 1e-6), 1000 * max(row["spread_m"], 1e-6)),
                        fontsize=7, xytext=(3, 3), textcoords="offset points", color=colours(i))
    ax.set_xscale("log")
    ax.set_yscale("log")
    low = 1000 * min(table["bias_m"].clip(lower=1e-6).min(), table["spread_m"].clip(lower=1e-6).min())
    high = 1000 * max(table["bias_m"].max(), table["spread_m"].max())
    ax.plot([low, high], [low, high], color="grey", lw=0.8, ls="--")
    ax.set_xlabel("bias: |mean theta~ - theta*| (1e-3 m)")
    ax.set_ylabel("spread: RMS |theta~ - mean| (1e-3 m)")
    ax.set_title("(b) bias vs spread (labels: noise level)", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)

    if runs is not None:
        ax = axes[2]
        noise_level = int(runs["noise_level"].max())
        for i, name in enumerate(methods):
            rows = runs[(runs["method"] == name) & (runs["noise_level"] == noise_level)]
            ax.scatter(1000 * (rows["a"] - shift[0]), 1000 * (rows["b"] - shift[1]), s=14, marker=markers[name],
                       color=colours(i), alpha=0.8, label=METHOD_LABELS.get(name, name))
        ax.axhline(0, color="grey", lw=0.8)
        ax.axvline(0, color="grey", lw=0.8)
        ax.set_xlabel("a~ - a* (1e-3 m)")
        ax.set_ylabel("b~ - b* (1e-3 m)")
        ax.set_title(f"(c) where theta~ lands, noise level {noise_level}", fontsize=10)
        ax.legend(fontsize=7)
        ax.grid(True, alpha=0.3)
    fig.suptitle("Table 3: SDM against the baselines (same training sets, same noise draws)", fontsize=11)
    return fig


# -- plain words ------------------------------------------------------------------------------------


def table3_summary(table: pd.DataFrame, reference: str = "sdm", table2_runs: int | None = None) -> str:
    """The answer to the paper's claim, in plain words from the measured Table 3 (Markdown).

    Per noise level: the best method by mean distance and how SDM compares with the best baseline
    (ratio of means, share of paired runs won); then each method's time per run relative to SDM's.
    Where Table 3 pairs fewer runs per level than Table 2 holds (``table2_runs``), a line says so and
    why. Every number in the text comes from ``table`` (and ``table2_runs``).
    """
    if reference not in set(table["method"]):
        raise SDMInputError(f"Table 3 has no {reference!r} rows to compare with")
    lines = []
    for noise_level, rows in table.groupby("noise_level", sort=True):
        ref = rows[rows["method"] == reference]
        others = rows[(rows["method"] != reference) & (rows["method"] != FLOOR)]
        if ref.empty or others.empty:
            continue
        ref_mean = float(ref["mean_m"].iloc[0])
        best_other = others.loc[others["mean_m"].idxmin()]
        ratio = float(best_other["mean_m"]) / ref_mean if ref_mean > 0 else math.inf
        runs = int(ref["runs"].iloc[0])
        if ratio > 1:
            verdict = (f"SDM wins: {1000 * ref_mean:.3f}e-3 m against {1000 * best_other['mean_m']:.3f}e-3 m for the best "
                       f"baseline ({best_other['label']}), {ratio:.1f} times SDM's mean")
        else:
            verdict = (f"SDM loses: {1000 * ref_mean:.3f}e-3 m against {1000 * best_other['mean_m']:.3f}e-3 m for "
                       f"{best_other['label']} ({1 / ratio:.1f} times closer than SDM on average)")
        beaten = [f"{row['label']} {row['wins_vs_sdm']:.0%}" for _, row in others.iterrows() if not math.isnan(row["wins_vs_sdm"])]
        lines.append(f"- noise level {int(noise_level)} ({runs} paired runs): {verdict}; share of paired runs closer to "
                     f"theta* than SDM's: {', '.join(beaten)}. SDM's bias {1000 * float(ref['bias_m'].iloc[0]):.3f}e-3 m, "
                     f"spread {1000 * float(ref['spread_m'].iloc[0]):.3f}e-3 m.")
    seconds = table[table["method"] != FLOOR].groupby("method", sort=False)["seconds_per_run"].mean()
    ref_seconds = float(seconds[reference])
    timing = ", ".join(
        f"{METHOD_LABELS.get(name, name)} {value:.2f} s" + (f" ({value / ref_seconds:.1f}x)" if ref_seconds > 0 else "")
        for name, value in seconds.items() if not math.isnan(value)
    )
    if math.isnan(ref_seconds):
        timing += " (SDM's rows come from Table 2, and no timing of its runs was given)"
    lines.append(f"- time per run (mean over levels, one thread; in brackets: relative to SDM): {timing}.")
    paired = int(table["runs"].max())
    if table2_runs is not None and paired < table2_runs:
        others = seconds.drop(reference).dropna()
        cost = (f": a baseline run costs {others.mean():.2f} s on average (the line above), "
                f"{others.mean() / ref_seconds:.0f} times SDM's" if len(others) and ref_seconds > 0 else "")
        lines.append(f"- runs: Table 3 pairs runs 0-{paired - 1} of Table 2's {table2_runs} per level (config key "
                     f"'baselines.runs'), fewer than Table 2 so that the default run stays within its time "
                     f"budget{cost}; set it to {table2_runs} to pair all of them.")
    return "\n".join(lines) + "\n"


# -- the floor --------------------------------------------------------------------------------------


def floor_frame(runs: pd.DataFrame) -> pd.DataFrame:
    """The floor per noise level from its per-run rows (:data:`FLOOR_RUN_COLUMNS`, metres).

    Returns:
        One row per level: ``noise_level, runs``; ``mean_m``, ``median_m`` of the floor's distance to theta*
        (the centre of each run's minimal region); ``search_mean_m`` (the search's own best points);
        ``half_mean_m`` (the floor found with half the budget) and ``budget_change`` (``|mean - half| /
        mean``: what doubling the budget moved); ``extent_a_m``, ``extent_b_m`` (mean width of the region
        where the count is minimal, along a and b); ``truth_minimal`` (share of runs where theta* itself
        has the minimal count); ``seconds_per_run``.
    """
    require_columns(runs, FLOOR_RUN_COLUMNS, "floor runs", runs=True)
    rows = []
    for noise_level, group in runs.groupby("noise_level", sort=True):
        mean, half = float(group["distance"].mean()), float(group["half_distance"].mean())
        rows.append({"noise_level": int(noise_level), "runs": int(len(group)), "mean_m": mean,
                     "median_m": float(group["distance"].median()), "search_mean_m": float(group["search_distance"].mean()),
                     "half_mean_m": half, "budget_change": abs(mean - half) / mean if mean > 0 else math.nan,
                     "extent_a_m": float(group["extent_a"].mean()), "extent_b_m": float(group["extent_b"].mean()),
                     "truth_minimal": float((group["mismatch_at_truth"] == group["min_mismatch"]).mean()),
                     "seconds_per_run": float(group["seconds"].mean())})
    return pd.DataFrame.from_records(rows)


def floor_summary(frame: pd.DataFrame, settings: Mapping) -> str:
    """The floor in plain words (Markdown, one bullet), every number from :func:`floor_frame`'s ``frame``
    and the search's ``settings`` (``sdm.experiments.baselines.floor.FloorSettings`` fields, as a mapping). No measured
    time: the words are deterministic, like the tables (the time is the table's ``s / run`` column)."""
    runs = ", ".join(sorted({str(int(r)) for r in frame["runs"]}))
    per_level = "; ".join(
        f"level {int(row.noise_level)}: {1e3 * row.mean_m:.3f} (region {1e3 * row.extent_a_m:.3f} x {1e3 * row.extent_b_m:.3f} "
        f"along a x b; theta* minimal in {row.truth_minimal:.0%} of runs)" for row in frame.itertuples())
    worst = frame.loc[frame["budget_change"].idxmax()]
    budget = ", ".join(f"{key} {value}" for key, value in sorted(settings.items()))
    return (f"- floor (exact-mismatch minimiser; {runs} runs per level; search: {budget}): per run, the centre of "
            f"the region of theta where the exact zoom-0 pixel mismatch of its noisy training set is minimal, the "
            f"best any method minimising CMA-ES's objective can reach. Mean distance (1e-3 m) and the region's mean "
            f"extent (1e-3 m): {per_level}. Doubling the budget (the same search stopped after half of it against "
            f"all of it) moves a level's mean by at most {worst['budget_change']:.1%} (level {int(worst['noise_level'])}); "
            f"its time per run is Table 3's `s / run`.\n")

"""Beyond the paper: Table 4 (Table 2 per gradient rule) and Table 5 (the shift with depth).

Table 4 puts each rule's runs beside the paper's rule's own runs with the same noise draws (Table 2's
runs ``0 .. runs-1``), the paper's published Table 2 and the bar "half the paper's mean": at most half the
paper's published mean at each noisy level, at most the paper's noise-free mean (0.682e-3 m) at level 0.
Table 5 gives, per true depth shift ``c*`` and noise level, the mean absolute errors of ``a``, ``b``
and ``c`` and the distance to ``theta* = (a*, b*, c*)``, against the depth bar for the noise-free
runs (``a``, ``b`` within 2e-3 m and ``c`` within 2e-2 m, mean over the runs).

Units: the CSVs keep metres (``*_m``); the Markdown and LaTeX tables show 1e-3 m, like Table 2.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from ..errors import SDMInputError
from .. import paper
from ..train import parse_schedule
from .io import read_csv
from .tables import TableFormat, in_millimetres, write_table

#: The depth bar for the noise-free runs (metres): mean |a - a*|, |b - b*| and |c - c*|.
DEPTH_BAR_M = {"a": 2e-3, "b": 2e-3, "c": 2e-2}

#: Per-run columns Table 4 needs (``sdm.experiments.rule_noise_runs``; Table 2's runs have no ``flow``).
RULE_RUN_COLUMNS = ("flow", "level", "run", "distance")

#: Table 4's rows that are not gradient rules: the best black-box search (Table 3's CMA-ES runs) and the
#: floor (the exact-mismatch minimiser of each run, :mod:`sdm.baselines.floor`), on their own paired runs.
CMAES_ROW = "CMA-ES (Table 3)"
FLOOR_ROW = "floor (exact-mismatch minimiser)"
#: The bar "within 2x of CMA-ES": a gradient rule's mean distance at most this many times CMA-ES's, on the same runs.
CMAES_FACTOR = 2.0


def reference_rows(baseline_runs: pd.DataFrame | None, floor_runs: pd.DataFrame | None) -> pd.DataFrame:
    """CMA-ES's runs (``method == "cmaes"`` of Table 3's per-run rows) and the floor's runs as Table 4 rows
    (``flow`` :data:`CMAES_ROW` / :data:`FLOOR_ROW`, ``level, run, distance``); either may be ``None``."""
    parts = []
    if baseline_runs is not None and "cmaes" in set(baseline_runs.get("method", ())):
        cmaes = baseline_runs[baseline_runs["method"] == "cmaes"]
        parts.append(cmaes[["level", "run", "distance"]].assign(flow=CMAES_ROW))
    if floor_runs is not None and len(floor_runs):
        parts.append(floor_runs[["level", "run", "distance"]].assign(flow=FLOOR_ROW))
    if not parts:
        return pd.DataFrame(columns=list(RULE_RUN_COLUMNS))
    return pd.concat(parts, ignore_index=True)[list(RULE_RUN_COLUMNS)]
#: Per-run columns Table 5 needs (``sdm.experiments.DEPTH_RUN_COLUMNS``).
DEPTH_RUN_COLUMNS = ("c_true", "level", "run", "c", "error_a", "error_b", "error_c", "distance_ab", "distance")


def _require(frame: pd.DataFrame, columns: Sequence[str], what: str) -> None:
    missing = [c for c in columns if c not in frame]
    if missing:
        raise SDMInputError(f"{what}: missing column(s) {missing}; has {list(frame.columns)}")
    if frame.empty:
        raise SDMInputError(f"{what}: no run")


def half_paper_mean_m(level: int) -> float:
    """The bar "half the paper's mean" on a rule's mean distance at ``level`` (metres): half the paper's published
    Table 2 mean at a noisy level, the paper's own mean noise-free; NaN where the paper has no level."""
    published = paper.TABLE2.get(int(level))
    if published is None:
        return math.nan
    return 1e-3 * published["mean"] * (1.0 if int(level) == 0 else 0.5)


def _stats(values: np.ndarray) -> dict[str, float]:
    return {"mean_m": float(values.mean()),
            "std_m": float(values.std(ddof=1)) if values.size > 1 else math.nan,
            "median_m": float(np.median(values))}


def gathered_runs(paths: Sequence[str | Path], keys: Sequence[str], expected: set, what: str) -> pd.DataFrame:
    """The run files at ``paths`` (CSVs, one row per run) concatenated, checked to hold exactly the runs
    ``expected`` (tuples of the columns ``keys``, e.g. ``(flow, level, run)``); ``what`` names the table in
    the error. The gathering stages of Tables 4 and 5 read their jobs' files with it."""
    frame = pd.concat([read_csv(path) for path in paths], ignore_index=True)
    found = set(zip(*(frame[key] for key in keys)))
    if found != expected:
        raise SDMInputError(f"{what}: missing runs {sorted(expected - found)[:5]}, unexpected {sorted(found - expected)[:5]}")
    return frame


# -- Table 4 ------------------------------------------------------------------------------------------


def table4_frame(rule_runs: pd.DataFrame, table2_runs: pd.DataFrame,
                 cmaes_runs: pd.DataFrame | None = None) -> pd.DataFrame:
    """Table 4: Table 2 again for each gradient rule, with the paper's rule's paired runs beside.

    Args:
        rule_runs: one row per (flow, level, run) with :data:`RULE_RUN_COLUMNS` (distance in metres).
        table2_runs: Table 2's runs (``level, run, distance``: the paper's rule on the same noise
            draws); only the (level, run) pairs that ``rule_runs`` has are used, so the
            comparison is paired.

    Returns:
        One row per (flow, level), rules in the order they first appear: ``flow, level, runs``;
        ``mean_m, std_m, median_m`` of the rule's distances; ``paper_rule_mean_m, paper_rule_std_m,
        paper_rule_median_m`` (Table 2's runs of the same (level, run)) and ``paper_rule_runs``;
        ``published_mean_m, published_std_m, published_median_m`` (the paper's Table 2, NaN for a
        level it lacks); ``bar_m`` (:func:`half_paper_mean_m`), ``meets_bar`` (``mean_m <= bar_m``) and
        ``ratio_to_paper_rule`` (``mean_m / paper_rule_mean_m``). With ``cmaes_runs`` (rows ``level, run,
        distance``: Table 3's CMA-ES) also the comparison with CMA-ES on the runs both have: ``cmaes_runs``
        (their number), ``on_cmaes_runs_mean_m`` (the row's mean over them), ``cmaes_mean_m``,
        ``ratio_to_cmaes`` and ``within_2x_cmaes`` (ratio at most :data:`CMAES_FACTOR`).
    """
    _require(rule_runs, RULE_RUN_COLUMNS, "Table 4 rule runs")
    _require(table2_runs, ("level", "run", "distance"), "Table 2 runs")
    reference = table2_runs.set_index(["level", "run"])["distance"]
    search = cmaes_runs.set_index(["level", "run"])["distance"] if cmaes_runs is not None and len(cmaes_runs) else None
    rows = []
    for flow in pd.unique(rule_runs["flow"]):
        for level, group in rule_runs[rule_runs["flow"] == flow].groupby("level", sort=True):
            ours = _stats(group["distance"].to_numpy(dtype=float))
            pairs = pd.MultiIndex.from_arrays([group["level"], group["run"]])
            paired = reference.reindex(pairs).dropna().to_numpy(dtype=float)
            theirs = _stats(paired) if paired.size else dict.fromkeys(("mean_m", "std_m", "median_m"), math.nan)
            published = paper.TABLE2.get(int(level), {})
            bar = half_paper_mean_m(level)
            row = {"flow": str(flow), "level": int(level), "runs": int(len(group)), **ours}
            row |= {f"paper_rule_{key}": value for key, value in theirs.items()} | {"paper_rule_runs": int(paired.size)}
            row |= {f"published_{stat}_m": 1e-3 * published[key] if published else math.nan
                    for stat, key in (("mean", "mean"), ("std", "std"), ("median", "q2"))}
            row |= {"bar_m": bar, "meets_bar": bool(ours["mean_m"] <= bar) if not math.isnan(bar) else False,
                    "ratio_to_paper_rule": ours["mean_m"] / theirs["mean_m"] if theirs["mean_m"] > 0 else math.nan}
            if search is not None:
                row |= _against_cmaes(group, search)
            rows.append(row)
    return pd.DataFrame.from_records(rows)


def _against_cmaes(group: pd.DataFrame, search: pd.Series) -> dict:
    """The CMA-ES columns for one (row, level): the row's and CMA-ES's means over the runs both have."""
    own = group.set_index(["level", "run"])["distance"]
    common = own.index.intersection(search.index)
    if not len(common):
        return {"cmaes_runs": 0, "on_cmaes_runs_mean_m": math.nan, "cmaes_mean_m": math.nan,
                "ratio_to_cmaes": math.nan, "within_2x_cmaes": False}
    mine, theirs = float(own.loc[common].mean()), float(search.loc[common].mean())
    ratio = mine / theirs if theirs > 0 else math.nan
    return {"cmaes_runs": int(len(common)), "on_cmaes_runs_mean_m": mine, "cmaes_mean_m": theirs,
            "ratio_to_cmaes": ratio, "within_2x_cmaes": bool(ratio <= CMAES_FACTOR)}


_TABLE4_DISTANCES = ("mean", "std", "median", "paper_rule_mean", "paper_rule_std", "paper_rule_median",
                     "published_mean", "published_std", "published_median", "bar", "on_cmaes_runs_mean",
                     "cmaes_mean")

TABLE4_FORMAT = TableFormat(
    columns=("flow", "level", "runs", "mean", "std", "median", "paper_rule_mean", "paper_rule_std",
             "paper_rule_median", "published_mean", "published_median", "bar", "meets_bar", "ratio_to_paper_rule",
             "cmaes_runs", "on_cmaes_runs_mean", "cmaes_mean", "ratio_to_cmaes"),
    headers={
        "flow": "rule", "level": "noise level", "runs": "runs", "mean": "mean", "std": "std", "median": "median",
        "paper_rule_mean": "mean (paper's rule)", "paper_rule_std": "std (paper's rule)",
        "paper_rule_median": "median (paper's rule)", "published_mean": "mean (paper)",
        "published_median": "median (paper)", "bar": "bar", "meets_bar": "meets bar",
        "ratio_to_paper_rule": "mean / paper's rule", "cmaes_runs": "runs with CMA-ES",
        "on_cmaes_runs_mean": "mean (those runs)", "cmaes_mean": "CMA-ES mean", "ratio_to_cmaes": "/ CMA-ES",
    },
    formats={c: ".3f" for c in _TABLE4_DISTANCES} | {"ratio_to_paper_rule": ".2f", "ratio_to_cmaes": ".2f"},
    caption="Table 4: Table 2 per gradient rule, distance ||theta~ - theta*|| per noise level (1e-3 m)",
    label="tab:table4",
    notes=(
        "Each rule's run r at level n trains on the noisy targets and shuffling of Table 2's run r (the same seed). "
        "paper's rule: Table 2's runs with the same (level, run); paper: the published Table 2. "
        "bar: half the paper's mean at levels 1-4, the paper's mean noise-free.",
        f"{CMAES_ROW}: Table 3's CMA-ES runs, all that its stage ran (baselines.runs_by_method; Table 3 itself reads "
        f"the first baselines.runs of them); {FLOOR_ROW}: per run, the theta minimising the exact zoom-0 pixel "
        "mismatch (CMA-ES's objective) over that run's noisy training set, the centre of the region where it is "
        "minimal (sdm.baselines.floor). The last four columns compare each row with CMA-ES on the runs both have "
        "(bar: within 2x of CMA-ES's mean).",
    ),
)


def table4_display(frame: pd.DataFrame) -> pd.DataFrame:
    """Table 4 for Markdown / LaTeX: distances in 1e-3 m under the short names of :data:`TABLE4_FORMAT`."""
    return in_millimetres(frame, _TABLE4_DISTANCES)


def table4_summary(frame: pd.DataFrame) -> str:
    """Table 4 in plain words (Markdown): per rule, whether it meets the bar "half the paper's mean" at every
    level, where it misses, how far it moves the mean from the paper's rule's on the same draws, and (where the
    table has CMA-ES's columns) the bar "within 2x of CMA-ES": within :data:`CMAES_FACTOR` times CMA-ES's mean
    at every level, on the runs both have, and by how much it misses where it does. The floor's and CMA-ES's own
    rows are stated as what the rules are read against, not judged."""
    lines = []
    rules = [flow for flow in pd.unique(frame["flow"]) if flow not in (CMAES_ROW, FLOOR_ROW)]
    for flow in rules:
        rows = frame[frame["flow"] == flow].sort_values("level")
        judged = rows[rows["bar_m"].notna()]
        missed = judged[~judged["meets_bar"]]
        runs = ", ".join(sorted({str(int(r)) for r in rows["runs"]}))
        per_level = "; ".join(
            f"level {int(row.level)}: {1e3 * row.mean_m:.3f} against {1e3 * row.paper_rule_mean_m:.3f} for the "
            f"paper's rule ({row.ratio_to_paper_rule:.2f}x), bar {1e3 * row.bar_m:.3f}"
            for row in rows.itertuples())
        if judged.empty:
            verdict = "no level of the paper's Table 2 was run, so the bar does not apply"
        elif missed.empty:
            verdict = f"meets the bar (half the paper's mean) at every level run ({len(judged)} of {len(judged)})"
        else:
            verdict = ("misses the bar (half the paper's mean) at level "
                       + ", ".join(str(int(v)) for v in missed["level"])
                       + f" and meets it at {len(judged) - len(missed)} of {len(judged)} levels")
        lines.append(f"- rule `{flow}` ({runs} runs per level) {verdict}. Mean distance (1e-3 m): {per_level}.")
        if "ratio_to_cmaes" in rows and (rows["cmaes_runs"] > 0).any():
            lines.append(_cmaes_verdict(flow, rows))
            lines += _refinement_reading(flow, rows, frame)
    for name in (CMAES_ROW, FLOOR_ROW):
        rows = frame[frame["flow"] == name].sort_values("level")
        if len(rows):
            runs = ", ".join(sorted({str(int(r)) for r in rows["runs"]}))
            means = "; ".join(f"level {int(row.level)}: {1e3 * row.mean_m:.3f}" for row in rows.itertuples())
            what = ("the best black-box search of Table 3, on the exact pixel mismatch" if name == CMAES_ROW else
                    "the best any method minimising CMA-ES's objective can reach on these runs")
            lines.append(f"- {name}, {what} ({runs} runs per level). Mean distance (1e-3 m): {means}.")
    return "\n".join(lines) + "\n"


#: The time bar "at most 1.5x the paper's rule's time": a rule's time per run at most this many times the
#: paper's rule's (Table 2's runs).
TIME_FACTOR = 1.5


def rule_times(rule_runs: pd.DataFrame, sdm_timings: Sequence[dict]) -> str:
    """Each rule's time per run beside the paper's rule's, in words (Markdown), every number measured.

    Args:
        rule_runs: Table 4's runs with ``seconds`` (a run's share of its level's wall time, ``rule_runs``).
        sdm_timings: Table 2's noise jobs' records ``{"runs", "seconds"}`` (the same measure: the wall time of
            the runs trained together, without the job's start-up).

    Returns:
        One line per rule with the time bar (at most :data:`TIME_FACTOR` times the paper's rule), or ``""``
        where either side has no timing.
    """
    runs = sum(int(record["runs"]) for record in sdm_timings)
    if "seconds" not in rule_runs or not runs:
        return ""
    paper_rule = sum(float(record["seconds"]) for record in sdm_timings) / runs
    lines = []
    for flow in pd.unique(rule_runs["flow"]):
        own = float(rule_runs.loc[rule_runs["flow"] == flow, "seconds"].mean())
        ratio = own / paper_rule
        verdict = "within" if ratio <= TIME_FACTOR else "beyond"
        lines.append(f"- time per run of rule `{flow}`: {own:.3f} s against {paper_rule:.3f} s for the paper's rule "
                     f"(Table 2's {runs} runs, the same measure: wall time of the runs trained together, one thread), "
                     f"{ratio:.2f}x: {verdict} the bar of {TIME_FACTOR:g}x the paper's rule's time.")
    return "\n".join(lines) + "\n"


def _cmaes_verdict(flow: str, rows: pd.DataFrame) -> str:
    """The bar "within 2x of CMA-ES" for one rule's rows of Table 4, in words, every number from the rows."""
    judged = rows[rows["cmaes_runs"] > 0]
    missed = judged[~judged["within_2x_cmaes"]]
    runs = ", ".join(sorted({str(int(r)) for r in judged["cmaes_runs"]}))
    if missed.empty:
        return (f"  Against CMA-ES on the same {runs} runs per level (bar: within {CMAES_FACTOR:g}x of CMA-ES's "
                f"mean): met at every level ({len(judged)} of {len(judged)}).")
    worst = missed.loc[missed["ratio_to_cmaes"].idxmax()]
    by_level = "; ".join(f"level {int(row.level)}: {1e3 * row.on_cmaes_runs_mean_m:.3f} against "
                         f"{1e3 * row.cmaes_mean_m:.3f} ({row.ratio_to_cmaes:.1f}x)" for row in judged.itertuples())
    return (f"  Against CMA-ES on the same {runs} runs per level (bar: within {CMAES_FACTOR:g}x of CMA-ES's mean): "
            f"missed at level {', '.join(str(int(v)) for v in missed['level'])}, met at {len(judged) - len(missed)} of "
            f"{len(judged)}; the worst miss is level {int(worst['level'])}, {worst['ratio_to_cmaes']:.1f}x CMA-ES's "
            f"mean ({worst['ratio_to_cmaes'] / CMAES_FACTOR:.1f} times the bar). Mean distance (1e-3 m): {by_level}.")


def _refinement_reading(flow: str, rows: pd.DataFrame, frame: pd.DataFrame) -> list[str]:
    """Where a schedule ``RULE+REFINE:E`` misses the CMA-ES bar, what the table measures about why (Markdown):
    at each missed level, where its first rule alone ends (that rule's row, on the same runs), where the
    refinement takes it and CMA-ES's mean, so the share of the first rule's gap to CMA-ES that the refinement
    closes. No line where the schedule meets the bar or the table has no row of its first rule alone."""
    first, plus, refine = flow.partition("+")
    alone = frame[frame["flow"] == first].set_index("level")
    missed = rows[(rows["cmaes_runs"] > 0) & ~rows["within_2x_cmaes"].astype(bool)]
    if not plus or missed.empty or alone.empty or "on_cmaes_runs_mean_m" not in alone:
        return []
    parts = []
    for row in missed.itertuples():
        if row.level not in alone.index:
            continue
        start, cmaes = float(alone.loc[row.level, "on_cmaes_runs_mean_m"]), float(row.cmaes_mean_m)
        closed = (start - row.on_cmaes_runs_mean_m) / (start - cmaes) if start > cmaes else math.nan
        parts.append(f"level {int(row.level)}: `{first}` alone ends at {1e3 * start:.3f}, the refinement at "
                     f"{1e3 * row.on_cmaes_runs_mean_m:.3f}, CMA-ES {1e3 * cmaes:.3f} ({max(100 * closed, 0):.0f}% of "
                     f"the gap closed)")
    if not parts:
        return []

    widths = parse_schedule(flow)[1].widths
    return [f"  Why it misses, measured on the same runs (1e-3 m): the refinement (`{refine}`) starts where `{first}` "
            f"ends; per missed level: " + "; ".join(parts) + ". The refinement's rule pulls theta only "
            f"towards the pixel crossings within its kernel's half-width, {1e3 * widths[0]:g}e-3 m of theta on its "
            f"first pass narrowing to {1e3 * widths[-1]:g}e-3 m on its last (docs/method/floor.md, \"The refinement "
            "on the real sample\": the steps, rates and widths measured)."]


#: Columns of the rules' fixed-point measurement (:func:`sdm.experiments.rule_bias`, plus ``flow``).
BIAS_COLUMNS = ("flow", "level", "bias_a", "stiffness_a", "offset_a", "bias_b", "stiffness_b", "offset_b",
                "predicted_m")


def bias_summary(bias: pd.DataFrame, frame: pd.DataFrame) -> str:
    """Why each rule lands where it does, measured (Markdown): per rule and level, where the mean flow of the
    last level vanishes (:func:`sdm.experiments.rule_bias`: its bias at theta* under noise over its stiffness
    near theta*), beside the rule's measured mean distance in Table 4 (``frame``; Table 2's for ``paper``)."""
    _require(bias, BIAS_COLUMNS, "the rules' bias")
    lines = []
    for flow in pd.unique(bias["flow"]):
        rows = bias[bias["flow"] == flow].sort_values("level")
        mine = frame[frame["flow"] == flow].set_index("level")["mean_m"] if flow in set(frame["flow"]) else (
            frame[~frame["flow"].isin((CMAES_ROW, FLOOR_ROW))].groupby("level")["paper_rule_mean_m"].first())
        parts = [f"level {int(row.level)}: bias ({row.bias_a:.2f}, {row.bias_b:.2f}) per configuration, stiffness "
                 f"({row.stiffness_a:.0f}, {row.stiffness_b:.0f}) per metre, fixed point {1e3 * row.predicted_m:.3f} "
                 f"from theta* against {1e3 * float(mine.get(row.level, math.nan)):.3f} measured"
                 for row in rows.itertuples()]
        lines.append(f"- rule `{flow}`, measured at the last level (zoom 0; run 0's draw; flow per configuration, "
                     f"distances 1e-3 m): " + "; ".join(parts) + ".")
    return ("Where each rule settles, measured: SGD stops on average where the last level's mean flow vanishes, "
            "about -bias / stiffness from theta* per axis (bias: the mean flow at theta* under noise; stiffness: its "
            "change per metre of theta near theta*, on the same draw). A rule misses where its bias is large "
            "against its stiffness, or where SGD's scatter adds to it (measured minus predicted).\n\n"
            + "\n".join(lines) + "\n")


def rules_against_baselines(rule_runs: pd.DataFrame, baseline_runs: pd.DataFrame) -> str:
    """Each rule of Table 4 beside Table 3's baselines, paired: the same (level, run), hence the same noisy targets.

    Args:
        rule_runs: per-run rows with ``flow, level, run, distance`` (metres).
        baseline_runs: Table 3's per-run rows with ``method, level, run, distance`` (metres).

    Returns:
        Markdown, one bullet per rule: per level its mean distance and the best baseline's over the
        same runs (1e-3 m), and how many baselines it beats; empty when no (level, run) is shared.
    """
    _require(rule_runs, RULE_RUN_COLUMNS, "Table 4's runs")
    _require(baseline_runs, ("method", "level", "run", "distance"), "Table 3's runs")
    lines = []
    for flow in pd.unique(rule_runs["flow"]):
        mine = rule_runs[rule_runs["flow"] == flow]
        parts, beaten_everywhere = [], True
        for level in sorted(pd.unique(mine["level"])):
            runs = set(mine.loc[mine["level"] == level, "run"])
            others = baseline_runs[(baseline_runs["level"] == level) & baseline_runs["run"].isin(runs)]
            if others.empty:
                continue
            counts = others.groupby("method")["run"].nunique()
            others = others[others["method"].isin(counts[counts == len(runs)].index)]  # only fully paired methods
            if others.empty:
                continue
            own = float(mine.loc[mine["level"] == level, "distance"].mean())
            means = others.groupby("method")["distance"].mean()
            best = str(means.idxmin())
            beaten = int((means > own).sum())
            beaten_everywhere &= beaten == len(means)
            parts.append(f"level {int(level)}: {1e3 * own:.3f} against {1e3 * float(means[best]):.3f} for `{best}`, the "
                         f"best baseline (beats {beaten} of {len(means)})")
        if parts:
            verdict = ("beats every baseline at every level" if beaten_everywhere
                       else "does not beat every baseline at every level")
            lines.append(f"- rule `{flow}` beside Table 3's baselines on the same runs {verdict}. Mean distance "
                         f"(1e-3 m): " + "; ".join(parts) + ".")
    return "\n".join(lines) + "\n" if lines else ""


# -- Table 5 ------------------------------------------------------------------------------------------


def table5_frame(depth_runs: pd.DataFrame) -> pd.DataFrame:
    """Table 5: the shift with depth, per true ``c*`` and noise level.

    Args:
        depth_runs: one row per (c_true, level, run) with :data:`DEPTH_RUN_COLUMNS` (metres).

    Returns:
        One row per (c_true, level), sorted: ``c_true, level, runs``; the means over the runs of
        ``error_a_m, error_b_m, error_c_m`` (absolute errors), ``bias_c_m`` (the signed mean of ``c - c*``: positive
        is too far), ``distance_ab_m`` and ``distance_m``
        (to ``(a*, b*)`` and to ``(a*, b*, c*)``), ``distance_std_m``; ``meets_bar`` (noise-free
        rows only, :data:`DEPTH_BAR_M`; ``False`` at noisy levels, where none is set).
    """
    _require(depth_runs, DEPTH_RUN_COLUMNS, "Table 5 depth runs")
    rows = []
    for (c_true, level), group in depth_runs.groupby(["c_true", "level"], sort=True):
        row = {"c_true": float(c_true), "level": int(level), "runs": int(len(group))}
        for column in ("error_a", "error_b", "error_c", "distance_ab", "distance"):
            row[f"{column}_m"] = float(group[column].mean())
        row["bias_c_m"] = float((group["c"] - group["c_true"]).mean())
        row["distance_std_m"] = float(group["distance"].std(ddof=1)) if len(group) > 1 else math.nan
        row["meets_bar"] = bool(int(level) == 0 and all(row[f"error_{axis}_m"] <= bar for axis, bar in DEPTH_BAR_M.items()))
        rows.append(row)
    return pd.DataFrame.from_records(rows)


_TABLE5_DISTANCES = ("error_a", "error_b", "error_c", "bias_c", "distance_ab", "distance", "distance_std")

TABLE5_FORMAT = TableFormat(
    columns=("c_true", "level", "runs", "error_a", "error_b", "error_c", "bias_c", "distance_ab", "distance",
             "distance_std", "meets_bar"),
    headers={
        "c_true": "c* (m)", "level": "noise level", "runs": "runs", "error_a": "|a - a*|", "error_b": "|b - b*|",
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
        for row in rows.sort_values("level").itertuples():
            errors = (f"|a - a*| {1e3 * row.error_a_m:.3f}, |b - b*| {1e3 * row.error_b_m:.3f}, "
                      f"|c - c*| {1e3 * row.error_c_m:.3f}")
            if row.level == 0:
                verdict = "meets" if row.meets_bar else "misses"
                parts.append(f"noise-free {errors} ({verdict} the bar of 2, 2 and 20)")
            else:
                parts.append(f"level {row.level} {errors}")
        runs = ", ".join(sorted({str(int(r)) for r in rows["runs"]}))
        lines.append(f"- c* = {c_true:g} m ({runs} runs per level), mean errors in 1e-3 m: " + "; ".join(parts) + ".")
    if not (frame["level"] == 0).any():
        lines.append("- No noise-free level was run: the depth bar was not checked.")
    return "\n".join(lines) + "\n"


def table5_bias_summary(frame: pd.DataFrame, bias: pd.DataFrame) -> str:
    """Why ``c`` is biased, in plain words (Markdown): Table 5's signed mean ``c - c*`` beside what
    :func:`sdm.experiments.depth_bias` measured at theta* (one row per ``flow``, ``c_true``, ``level``, ``zoom``).

    Per c* and noisy level: the measured bias, then each measured rule's predicted fixed point of ``c`` and the
    share of its depth flow that comes from the points at the edges of the discs, with how often those land on
    empty blocks against the other points.
    """
    lines = []
    measured = {(float(row.c_true), int(row.level)): row.bias_c_m for row in frame.itertuples()}
    for (c_true, level), rows in bias[bias["level"] > 0].groupby(["c_true", "level"], sort=True):
        parts = [f"{row.flow} at zoom {int(row.zoom)}: predicted {1e3 * row.offset_c:+.2f}, "
                 f"{100 * row.edge_share:.0f}% of its pull from disc edges (their points on empty blocks "
                 f"{100 * row.unmatched_edge:.1f}%, the others {100 * row.unmatched_inside:.1f}%)"
                 for row in rows.itertuples()]
        runs = measured.get((float(c_true), int(level)))
        head = f"mean c - c* {1e3 * runs:+.2f}" if runs is not None else "no runs"
        lines.append(f"- c* = {c_true:g} m, level {int(level)} (1e-3 m): {head}; " + "; ".join(parts) + ".")
    return "\n".join(lines) + "\n" if lines else ""


def beyond_the_paper(table4: str = "", table4_summary: str = "", table5: str = "", table5_summary: str = "") -> str:
    """The report's section "Beyond the paper" (Markdown) from the tables' Markdown and plain-word summaries.

    Only the parts given (non-empty) appear; with none, the empty string.
    """
    parts = []
    if table4_summary:
        parts.append("### Another gradient rule on Table 2's noisy targets (Table 4)\n\n"
                     "The paper's rule settles beyond theta* under noise (see above). Table 4 repeats Table 2 "
                     "with the other rules, each run on the same noisy targets and shuffling as Table 2's run; "
                     "the bar is half the paper's published mean at each noisy level.\n\n"
                     + table4_summary + "\n" + table4)
    if table5_summary:
        parts.append("### The shift with depth, (a, b, c) (Table 5)\n\n"
                     "The paper poses the shift with depth and solves only (a, b). Table 5 trains (a, b, c) with "
                     "the depth flow on the training set retargeted to theta* = (a*, b*, c*); the bar, "
                     "noise-free, is a, b within 2e-3 m and c within 2e-2 m (mean over the runs).\n\n"
                     + table5_summary + "\n" + table5)
    if not parts:
        return ""
    return "\n## Beyond the paper\n\n" + "\n".join(parts)


# -- writing and figures ------------------------------------------------------------------------------


def write_research_table(frame: pd.DataFrame, stem: str | Path, which: int) -> list[Path]:
    """``stem.csv`` (metres, full precision), ``stem.md`` and ``stem.tex`` (1e-3 m) of Table 4 or 5, atomically."""
    if which not in (4, 5):
        raise SDMInputError(f"which must be 4 or 5 (the table), got {which!r}")
    shown, style = (table4_display(frame), TABLE4_FORMAT) if which == 4 else (table5_display(frame), TABLE5_FORMAT)
    return write_table(frame, stem, style, shown)


def rules_figure(frame: pd.DataFrame):
    """Mean distance per noise level for each rule, the paper's rule on the same draws, the paper and the bar.

    Args:
        frame: :func:`table4_frame`.

    Returns:
        A matplotlib figure (log scale, 1e-3 m).
    """
    from .figures import plt  # the report's matplotlib, already on the Agg backend

    fig, ax = plt.subplots(figsize=(6.4, 4.4), constrained_layout=True)
    colours = plt.get_cmap("tab10")
    rules = [flow for flow in pd.unique(frame["flow"]) if flow not in (CMAES_ROW, FLOOR_ROW)]
    first = frame[frame["flow"] == (rules or list(pd.unique(frame["flow"])))[0]].sort_values("level")
    ax.plot(first["level"], 1e3 * first["paper_rule_mean_m"], marker="s", color="black",
            label="paper's rule (Table 2's runs)")
    ax.plot(first["level"], 1e3 * first["published_mean_m"], ls=":", color="black", label="paper (published)")
    ax.plot(first["level"], 1e3 * first["bar_m"], ls="--", color="grey", label="half the paper's mean (bar)")
    for i, flow in enumerate(rules):
        rows = frame[frame["flow"] == flow].sort_values("level")
        ax.errorbar(rows["level"], 1e3 * rows["mean_m"], yerr=1e3 * rows["std_m"].fillna(0.0), marker="o",
                    capsize=3, color=colours(i), label=f"rule {flow}")
    search = frame[frame["flow"] == CMAES_ROW].sort_values("level")
    if len(search):
        ax.plot(search["level"], 1e3 * search["mean_m"], marker="^", color="tab:red", label=CMAES_ROW)
        ax.plot(search["level"], CMAES_FACTOR * 1e3 * search["mean_m"], ls="-.", color="tab:red", lw=0.8,
                label=f"{CMAES_FACTOR:g}x CMA-ES (bar)")
    floor = frame[frame["flow"] == FLOOR_ROW].sort_values("level")
    if len(floor):  # a band from the axis' bottom up to the floor's mean: no mismatch minimiser lands below, on average
        mean = 1e3 * floor["mean_m"]
        bottom = 0.3 * 1e3 * float(frame["mean_m"][frame["mean_m"] > 0].min())  # below every mean: a log axis
        ax.fill_between(floor["level"], bottom, mean, color="grey", alpha=0.25, label=f"below the {FLOOR_ROW}")
        ax.plot(floor["level"], mean, color="grey", lw=1.0)
        ax.set_ylim(bottom=bottom)
    ax.set_yscale("log")
    ax.set_xticks(sorted(frame["level"].unique()))
    ax.set_xlabel("noise level n (pixels)")
    ax.set_ylabel("mean ||theta~ - theta*|| (1e-3 m), +- std")
    ax.set_title("Table 4: Table 2 per gradient rule (same noise draws)", fontsize=10)
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)
    return fig


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
            rows = rows.sort_values("level")
            ax.plot(rows["level"], scale * rows[f"error_{axis}_m"], marker="o", color=colours(i), label=f"c* = {c_true:g} m")
        ax.axhline(scale * DEPTH_BAR_M[axis], ls="--", color="grey", lw=0.8, label="bar (noise-free)")
        ax.set_yscale("log")
        ax.set_xticks(sorted(frame["level"].unique()))
        ax.set_xlabel("noise level n (pixels)")
        ax.set_ylabel(f"mean |{axis} - {axis}*| ({unit})")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle("Table 5: the shift (a, b, c) with depth", fontsize=11)
    return fig

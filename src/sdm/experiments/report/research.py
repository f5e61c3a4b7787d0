"""Beyond the paper: Table 4 (Table 2 per gradient rule), the helpers Tables 4 and 5 share, and the report's
section on both (Table 5, the shift with depth: :mod:`sdm.experiments.report.depth`).

Table 4 puts each rule's runs beside the paper's rule's own runs with the same noise draws (Table 2's
runs ``0 .. runs-1``), the paper's published Table 2 and the bar "half the paper's mean": at most half the
paper's published mean at each noisy level, at most the paper's noise-free mean (0.682e-3 m) at level 0.

Units: the CSVs keep metres (``*_m``); the Markdown and LaTeX tables show 1e-3 m, like Table 2.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from ...errors import SDMInputError
from .. import paper
from ...train import parse_schedule
from .io import read_csv
from .tables import TableFormat, in_millimetres, require_columns, write_table

#: Per-run columns Table 4 needs (``sdm.experiments.rule_noise_runs``; Table 2's runs have no ``rule``).
RULE_RUN_COLUMNS = ("rule", "noise_level", "run", "distance")

#: Table 4's rows that are not gradient rules: the best black-box search (Table 3's CMA-ES runs) and the
#: floor (the exact-mismatch minimiser of each run, :mod:`sdm.experiments.baselines.floor`), on their own paired runs.
CMAES_ROW = "CMA-ES (Table 3)"
FLOOR_ROW = "floor (exact-mismatch minimiser)"
#: The bar "within 2x of CMA-ES": a gradient rule's mean distance at most this many times CMA-ES's, on the same runs.
CMAES_FACTOR = 2.0


def reference_rows(baseline_runs: pd.DataFrame | None, floor_runs: pd.DataFrame | None) -> pd.DataFrame:
    """CMA-ES's runs (``method == "cmaes"`` of Table 3's per-run rows) and the floor's runs as Table 4 rows
    (``rule`` :data:`CMAES_ROW` / :data:`FLOOR_ROW`, ``noise_level, run, distance``); either may be ``None``."""
    parts = []
    if baseline_runs is not None and "cmaes" in set(baseline_runs.get("method", ())):
        cmaes = baseline_runs[baseline_runs["method"] == "cmaes"]
        parts.append(cmaes[["noise_level", "run", "distance"]].assign(rule=CMAES_ROW))
    if floor_runs is not None and len(floor_runs):
        parts.append(floor_runs[["noise_level", "run", "distance"]].assign(rule=FLOOR_ROW))
    if not parts:
        return pd.DataFrame(columns=list(RULE_RUN_COLUMNS))
    return pd.concat(parts, ignore_index=True)[list(RULE_RUN_COLUMNS)]
def half_paper_mean_m(noise_level: int) -> float:
    """The bar "half the paper's mean" on a rule's mean distance at ``noise_level`` (metres): half the paper's published
    Table 2 mean at a noisy level, the paper's own mean noise-free; NaN where the paper has no level."""
    published = paper.TABLE2.get(int(noise_level))
    if published is None:
        return math.nan
    return 1e-3 * published["mean"] * (1.0 if int(noise_level) == 0 else 0.5)


def run_stats(values: np.ndarray) -> dict[str, float]:
    return {"mean_m": float(values.mean()),
            "std_m": float(values.std(ddof=1)) if values.size > 1 else math.nan,
            "median_m": float(np.median(values))}


def gathered_runs(paths: Sequence[str | Path], keys: Sequence[str], expected: set, what: str) -> pd.DataFrame:
    """The run files at ``paths`` (CSVs, one row per run) concatenated, checked to hold exactly the runs
    ``expected`` (tuples of the columns ``keys``, e.g. ``(rule, noise_level, run)``); ``what`` names the table in
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
        rule_runs: one row per (rule, noise_level, run) with :data:`RULE_RUN_COLUMNS` (distance in metres).
        table2_runs: Table 2's runs (``noise_level, run, distance``: the paper's rule on the same noise
            draws); only the (noise_level, run) pairs that ``rule_runs`` has are used, so the
            comparison is paired.

    Returns:
        One row per (rule, level), rules in the order they first appear: ``rule, level, runs``;
        ``mean_m, std_m, median_m`` of the rule's distances; ``paper_rule_mean_m, paper_rule_std_m,
        paper_rule_median_m`` (Table 2's runs of the same (noise_level, run)) and ``paper_rule_runs``;
        ``published_mean_m, published_std_m, published_median_m`` (the paper's Table 2, NaN for a
        level it lacks); ``bar_m`` (:func:`half_paper_mean_m`), ``meets_bar`` (``mean_m <= bar_m``) and
        ``ratio_to_paper_rule`` (``mean_m / paper_rule_mean_m``). With ``cmaes_runs`` (rows ``noise_level, run,
        distance``: Table 3's CMA-ES) also the comparison with CMA-ES on the runs both have: ``cmaes_runs``
        (their number), ``on_cmaes_runs_mean_m`` (the row's mean over them), ``cmaes_mean_m``,
        ``ratio_to_cmaes`` and ``within_2x_cmaes`` (ratio at most :data:`CMAES_FACTOR`).
    """
    require_columns(rule_runs, RULE_RUN_COLUMNS, "Table 4 rule runs", runs=True)
    require_columns(table2_runs, ("noise_level", "run", "distance"), "Table 2 runs", runs=True)
    reference = table2_runs.set_index(["noise_level", "run"])["distance"]
    search = cmaes_runs.set_index(["noise_level", "run"])["distance"] if cmaes_runs is not None and len(cmaes_runs) else None
    rows = []
    for rule in pd.unique(rule_runs["rule"]):
        for noise_level, group in rule_runs[rule_runs["rule"] == rule].groupby("noise_level", sort=True):
            ours = run_stats(group["distance"].to_numpy(dtype=float))
            pairs = pd.MultiIndex.from_arrays([group["noise_level"], group["run"]])
            paired = reference.reindex(pairs).dropna().to_numpy(dtype=float)
            theirs = run_stats(paired) if paired.size else dict.fromkeys(("mean_m", "std_m", "median_m"), math.nan)
            published = paper.TABLE2.get(int(noise_level), {})
            bar = half_paper_mean_m(noise_level)
            row = {"rule": str(rule), "noise_level": int(noise_level), "runs": int(len(group)), **ours}
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
    own = group.set_index(["noise_level", "run"])["distance"]
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
    columns=("rule", "noise_level", "runs", "mean", "std", "median", "paper_rule_mean", "paper_rule_std",
             "paper_rule_median", "published_mean", "published_median", "bar", "meets_bar", "ratio_to_paper_rule",
             "cmaes_runs", "on_cmaes_runs_mean", "cmaes_mean", "ratio_to_cmaes"),
    headers={
        "rule": "rule", "noise_level": "noise level", "runs": "runs", "mean": "mean", "std": "std", "median": "median",
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
        "paper's rule: Table 2's runs with the same (noise_level, run); paper: the published Table 2. "
        "bar: half the paper's mean at levels 1-4, the paper's mean noise-free.",
        f"{CMAES_ROW}: Table 3's CMA-ES runs, all that its stage ran (baselines.runs_by_method; Table 3 itself reads "
        f"the first baselines.runs of them); {FLOOR_ROW}: per run, the theta minimising the exact zoom-0 pixel "
        "mismatch (CMA-ES's objective) over that run's noisy training set, the centre of the region where it is "
        "minimal (sdm.experiments.baselines.floor). The last four columns compare each row with CMA-ES on the runs both have "
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
    rules = [rule for rule in pd.unique(frame["rule"]) if rule not in (CMAES_ROW, FLOOR_ROW)]
    for rule in rules:
        rows = frame[frame["rule"] == rule].sort_values("noise_level")
        judged = rows[rows["bar_m"].notna()]
        missed = judged[~judged["meets_bar"]]
        runs = ", ".join(sorted({str(int(r)) for r in rows["runs"]}))
        per_level = "; ".join(
            f"level {int(row.noise_level)}: {1e3 * row.mean_m:.3f} against {1e3 * row.paper_rule_mean_m:.3f} for the "
            f"paper's rule ({row.ratio_to_paper_rule:.2f}x), bar {1e3 * row.bar_m:.3f}"
            for row in rows.itertuples())
        if judged.empty:
            verdict = "no level of the paper's Table 2 was run, so the bar does not apply"
        elif missed.empty:
            verdict = f"meets the bar (half the paper's mean) at every level run ({len(judged)} of {len(judged)})"
        else:
            verdict = ("misses the bar (half the paper's mean) at level "
                       + ", ".join(str(int(v)) for v in missed["noise_level"])
                       + f" and meets it at {len(judged) - len(missed)} of {len(judged)} levels")
        lines.append(f"- rule `{rule}` ({runs} runs per level) {verdict}. Mean distance (1e-3 m): {per_level}.")
        if "ratio_to_cmaes" in rows and (rows["cmaes_runs"] > 0).any():
            lines.append(_cmaes_verdict(rule, rows))
            lines += _refinement_reading(rule, rows, frame)
    for name in (CMAES_ROW, FLOOR_ROW):
        rows = frame[frame["rule"] == name].sort_values("noise_level")
        if len(rows):
            runs = ", ".join(sorted({str(int(r)) for r in rows["runs"]}))
            means = "; ".join(f"level {int(row.noise_level)}: {1e3 * row.mean_m:.3f}" for row in rows.itertuples())
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
    for rule in pd.unique(rule_runs["rule"]):
        own = float(rule_runs.loc[rule_runs["rule"] == rule, "seconds"].mean())
        ratio = own / paper_rule
        verdict = "within" if ratio <= TIME_FACTOR else "beyond"
        lines.append(f"- time per run of rule `{rule}`: {own:.3f} s against {paper_rule:.3f} s for the paper's rule "
                     f"(Table 2's {runs} runs, the same measure: wall time of the runs trained together, one thread), "
                     f"{ratio:.2f}x: {verdict} the bar of {TIME_FACTOR:g}x the paper's rule's time.")
    return "\n".join(lines) + "\n"


def _cmaes_verdict(rule: str, rows: pd.DataFrame) -> str:
    """The bar "within 2x of CMA-ES" for one rule's rows of Table 4, in words, every number from the rows."""
    judged = rows[rows["cmaes_runs"] > 0]
    missed = judged[~judged["within_2x_cmaes"]]
    runs = ", ".join(sorted({str(int(r)) for r in judged["cmaes_runs"]}))
    if missed.empty:
        return (f"  Against CMA-ES on the same {runs} runs per level (bar: within {CMAES_FACTOR:g}x of CMA-ES's "
                f"mean): met at every level ({len(judged)} of {len(judged)}).")
    worst = missed.loc[missed["ratio_to_cmaes"].idxmax()]
    by_level = "; ".join(f"level {int(row.noise_level)}: {1e3 * row.on_cmaes_runs_mean_m:.3f} against "
                         f"{1e3 * row.cmaes_mean_m:.3f} ({row.ratio_to_cmaes:.1f}x)" for row in judged.itertuples())
    return (f"  Against CMA-ES on the same {runs} runs per level (bar: within {CMAES_FACTOR:g}x of CMA-ES's mean): "
            f"missed at level {', '.join(str(int(v)) for v in missed['noise_level'])}, met at {len(judged) - len(missed)} of "
            f"{len(judged)}; the worst miss is level {int(worst['noise_level'])}, {worst['ratio_to_cmaes']:.1f}x CMA-ES's "
            f"mean ({worst['ratio_to_cmaes'] / CMAES_FACTOR:.1f} times the bar). Mean distance (1e-3 m): {by_level}.")


def _refinement_reading(rule: str, rows: pd.DataFrame, frame: pd.DataFrame) -> list[str]:
    """Where a schedule ``RULE+REFINE:E`` misses the CMA-ES bar, what the table measures about why (Markdown):
    at each missed level, where its first rule alone ends (that rule's row, on the same runs), where the
    refinement takes it and CMA-ES's mean, so the share of the first rule's gap to CMA-ES that the refinement
    closes. No line where the schedule meets the bar or the table has no row of its first rule alone."""
    first, plus, refine = rule.partition("+")
    alone = frame[frame["rule"] == first].set_index("noise_level")
    missed = rows[(rows["cmaes_runs"] > 0) & ~rows["within_2x_cmaes"].astype(bool)]
    if not plus or missed.empty or alone.empty or "on_cmaes_runs_mean_m" not in alone:
        return []
    parts = []
    for row in missed.itertuples():
        if row.noise_level not in alone.index:
            continue
        start, cmaes = float(alone.loc[row.noise_level, "on_cmaes_runs_mean_m"]), float(row.cmaes_mean_m)
        closed = (start - row.on_cmaes_runs_mean_m) / (start - cmaes) if start > cmaes else math.nan
        parts.append(f"level {int(row.noise_level)}: `{first}` alone ends at {1e3 * start:.3f}, the refinement at "
                     f"{1e3 * row.on_cmaes_runs_mean_m:.3f}, CMA-ES {1e3 * cmaes:.3f} ({max(100 * closed, 0):.0f}% of "
                     f"the gap closed)")
    if not parts:
        return []

    widths = parse_schedule(rule)[1].widths
    return [f"  Why it misses, measured on the same runs (1e-3 m): the refinement (`{refine}`) starts where `{first}` "
            f"ends; per missed level: " + "; ".join(parts) + ". The refinement's rule pulls theta only "
            f"towards the pixel crossings within its kernel's half-width, {1e3 * widths[0]:g}e-3 m of theta on its "
            f"first pass narrowing to {1e3 * widths[-1]:g}e-3 m on its last (docs/method/floor.md, \"The refinement "
            "on the real sample\": the steps, rates and widths measured)."]


#: Columns of the rules' fixed-point measurement (:func:`sdm.experiments.rule_bias`, plus ``rule``).
BIAS_COLUMNS = ("rule", "noise_level", "bias_a", "stiffness_a", "offset_a", "bias_b", "stiffness_b", "offset_b",
                "predicted_m")


def bias_summary(bias: pd.DataFrame, frame: pd.DataFrame) -> str:
    """Why each rule lands where it does, measured (Markdown): per rule and level, where the mean flow of the
    last level vanishes (:func:`sdm.experiments.rule_bias`: its bias at theta* under noise over its stiffness
    near theta*), beside the rule's measured mean distance in Table 4 (``frame``; Table 2's for ``paper``)."""
    require_columns(bias, BIAS_COLUMNS, "the rules' bias", runs=True)
    lines = []
    for rule in pd.unique(bias["rule"]):
        rows = bias[bias["rule"] == rule].sort_values("noise_level")
        mine = frame[frame["rule"] == rule].set_index("noise_level")["mean_m"] if rule in set(frame["rule"]) else (
            frame[~frame["rule"].isin((CMAES_ROW, FLOOR_ROW))].groupby("noise_level")["paper_rule_mean_m"].first())
        parts = [f"level {int(row.noise_level)}: bias ({row.bias_a:.2f}, {row.bias_b:.2f}) per configuration, stiffness "
                 f"({row.stiffness_a:.0f}, {row.stiffness_b:.0f}) per metre, fixed point {1e3 * row.predicted_m:.3f} "
                 f"from theta* against {1e3 * float(mine.get(row.noise_level, math.nan)):.3f} measured"
                 for row in rows.itertuples()]
        lines.append(f"- rule `{rule}`, measured at the last level (zoom 0; run 0's draw; flow per configuration, "
                     f"distances 1e-3 m): " + "; ".join(parts) + ".")
    return ("Where each rule settles, measured: SGD stops on average where the last level's mean flow vanishes, "
            "about -bias / stiffness from theta* per axis (bias: the mean flow at theta* under noise; stiffness: its "
            "change per metre of theta near theta*, on the same draw). A rule misses where its bias is large "
            "against its stiffness, or where SGD's scatter adds to it (measured minus predicted).\n\n"
            + "\n".join(lines) + "\n")


def rules_against_baselines(rule_runs: pd.DataFrame, baseline_runs: pd.DataFrame) -> str:
    """Each rule of Table 4 beside Table 3's baselines, paired: the same (noise_level, run), hence the same noisy targets.

    Args:
        rule_runs: per-run rows with ``rule, level, run, distance`` (metres).
        baseline_runs: Table 3's per-run rows with ``method, level, run, distance`` (metres).

    Returns:
        Markdown, one bullet per rule: per level its mean distance and the best baseline's over the
        same runs (1e-3 m), and how many baselines it beats; empty when no (noise_level, run) is shared.
    """
    require_columns(rule_runs, RULE_RUN_COLUMNS, "Table 4's runs", runs=True)
    require_columns(baseline_runs, ("method", "noise_level", "run", "distance"), "Table 3's runs", runs=True)
    lines = []
    for rule in pd.unique(rule_runs["rule"]):
        mine = rule_runs[rule_runs["rule"] == rule]
        parts, beaten_everywhere = [], True
        for noise_level in sorted(pd.unique(mine["noise_level"])):
            runs = set(mine.loc[mine["noise_level"] == noise_level, "run"])
            others = baseline_runs[(baseline_runs["noise_level"] == noise_level) & baseline_runs["run"].isin(runs)]
            if others.empty:
                continue
            counts = others.groupby("method")["run"].nunique()
            others = others[others["method"].isin(counts[counts == len(runs)].index)]  # only fully paired methods
            if others.empty:
                continue
            own = float(mine.loc[mine["noise_level"] == noise_level, "distance"].mean())
            means = others.groupby("method")["distance"].mean()
            best = str(means.idxmin())
            beaten = int((means > own).sum())
            beaten_everywhere &= beaten == len(means)
            parts.append(f"level {int(noise_level)}: {1e3 * own:.3f} against {1e3 * float(means[best]):.3f} for `{best}`, the "
                         f"best baseline (beats {beaten} of {len(means)})")
        if parts:
            verdict = ("beats every baseline at every level" if beaten_everywhere
                       else "does not beat every baseline at every level")
            lines.append(f"- rule `{rule}` beside Table 3's baselines on the same runs {verdict}. Mean distance "
                         f"(1e-3 m): " + "; ".join(parts) + ".")
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


def write_table4(frame: pd.DataFrame, stem: str | Path) -> list[Path]:
    """``stem.csv`` (metres, full precision), ``stem.md``, ``stem.tex`` and ``stem.html`` (1e-3 m) of Table 4,
    atomically."""
    return write_table(frame, stem, TABLE4_FORMAT, table4_display(frame))


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
    rules = [rule for rule in pd.unique(frame["rule"]) if rule not in (CMAES_ROW, FLOOR_ROW)]
    first = frame[frame["rule"] == (rules or list(pd.unique(frame["rule"])))[0]].sort_values("noise_level")
    ax.plot(first["noise_level"], 1e3 * first["paper_rule_mean_m"], marker="s", color="black",
            label="paper's rule (Table 2's runs)")
    ax.plot(first["noise_level"], 1e3 * first["published_mean_m"], ls=":", color="black", label="paper (published)")
    ax.plot(first["noise_level"], 1e3 * first["bar_m"], ls="--", color="grey", label="half the paper's mean (bar)")
    for i, rule in enumerate(rules):
        rows = frame[frame["rule"] == rule].sort_values("noise_level")
        ax.errorbar(rows["noise_level"], 1e3 * rows["mean_m"], yerr=1e3 * rows["std_m"].fillna(0.0), marker="o",
                    capsize=3, color=colours(i), label=f"rule {rule}")
    search = frame[frame["rule"] == CMAES_ROW].sort_values("noise_level")
    if len(search):
        ax.plot(search["noise_level"], 1e3 * search["mean_m"], marker="^", color="tab:red", label=CMAES_ROW)
        ax.plot(search["noise_level"], CMAES_FACTOR * 1e3 * search["mean_m"], ls="-.", color="tab:red", lw=0.8,
                label=f"{CMAES_FACTOR:g}x CMA-ES (bar)")
    floor = frame[frame["rule"] == FLOOR_ROW].sort_values("noise_level")
    if len(floor):  # a band from the axis' bottom up to the floor's mean: no mismatch minimiser lands below, on average
        mean = 1e3 * floor["mean_m"]
        bottom = 0.3 * 1e3 * float(frame["mean_m"][frame["mean_m"] > 0].min())  # below every mean: a log axis
        ax.fill_between(floor["noise_level"], bottom, mean, color="grey", alpha=0.25, label=f"below the {FLOOR_ROW}")
        ax.plot(floor["noise_level"], mean, color="grey", lw=1.0)
        ax.set_ylim(bottom=bottom)
    ax.set_yscale("log")
    ax.set_xticks(sorted(frame["noise_level"].unique()))
    ax.set_xlabel("noise level n (pixels)")
    ax.set_ylabel("mean ||theta~ - theta*|| (1e-3 m), +- std")
    ax.set_title("Table 4: Table 2 per gradient rule (same noise draws)", fontsize=10)
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)
    return fig

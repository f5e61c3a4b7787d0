"""The verdict (``results/report/verdict.md``): what a reader sees first, on the README's first screen.

One short table per noise level (the paper's Table 2 mean against ours, Table 3's best method, the
recommended rule of Table 4), the key figure, and one plain sentence each for what reproduced, what
did not, and whether SDM beats the alternatives. Every number comes from the measured tables handed
in (their CSVs) and the paper's values (:mod:`sdm.paper`); nothing is typed. ``make snapshot`` copies
the text into the README between its verdict markers (``workflow/scripts/snapshot.py``).

Only the methods and rules the run was configured with are compared (``methods``, ``rules``), so rows a
table may carry besides them (a reference row that is no method) never become "the best method".
"""
from __future__ import annotations

import math
from typing import Mapping, Sequence

import pandas as pd

from .. import paper
from .reproduction import NOISY_RATIO, checks
from .research import CMAES_FACTOR


def _levels(levels: Sequence[int]) -> str:
    """``[1, 2, 3, 4]`` -> ``"levels 1-4"``; ``[0, 2]`` -> ``"levels 0 and 2"``; ``[3]`` -> ``"level 3"``."""
    levels = sorted(int(level) for level in levels)
    if len(levels) == 1:
        return f"level {levels[0]}"
    if len(levels) > 2 and levels == list(range(levels[0], levels[-1] + 1)):
        return f"levels {levels[0]}-{levels[-1]}"
    return "levels " + ", ".join(str(level) for level in levels[:-1]) + f" and {levels[-1]}"


def best_methods(table3: pd.DataFrame, methods: Sequence[str]) -> pd.DataFrame:
    """Per noise level, the row of Table 3 (``method, label, level, mean_m``) with the lowest mean distance
    among ``methods`` (``sdm`` and the configured baselines)."""
    rows = table3[table3["method"].isin(list(methods))]
    return rows.loc[rows.groupby("level")["mean_m"].idxmin()].set_index("level")


def recommended_rule(table4: pd.DataFrame, rules: Sequence[str]) -> str | None:
    """The rule of Table 4 among ``rules`` that meets the bar "half the paper's mean" at the most levels, ties
    broken by the lower mean distance over its levels; None when no rule meets the bar at any level (keep the
    paper's)."""
    rows = table4[table4["flow"].isin(list(rules))]
    if rows.empty:
        return None
    score = rows.groupby("flow", sort=False).agg(met=("meets_bar", "sum"), mean=("mean_m", "mean"))
    score = score.sort_values(["met", "mean"], ascending=[False, True], kind="stable")
    return None if score["met"].iloc[0] == 0 else str(score.index[0])


def verdict(table1: pd.DataFrame, table2: pd.DataFrame, table3: pd.DataFrame | None = None,
            methods: Sequence[str] = (), table4: pd.DataFrame | None = None, rules: Sequence[str] = (),
            figure: str = "../figures/distances.png", data: str = "this run's data",
            elsewhere: Mapping[str, pd.DataFrame] | None = None, table6: pd.DataFrame | None = None,
            table7: pd.DataFrame | None = None) -> str:
    """The verdict's Markdown.

    Args:
        table1, table2: the CSVs of Tables 1 and 2 (:func:`sdm.report.tables.table1_frame`, ``table2_frame``;
            Table 2 in 1e-3 m).
        table3: Table 3's CSV (:func:`sdm.report.baselines.table3_frame`, metres), or None when it did not run;
            ``methods``: the methods compared in it (``sdm`` and the configured baselines).
        table4: Table 4's CSV (:func:`sdm.report.research.table4_frame`, metres), or None; ``rules``: the rules
            compared in it (the configured ones).
        figure: the key figure (Table 2's distances against the paper's), relative to the verdict's file.
        data: what this run's data is, in words (the recommended-rule line names it).
        elsewhere: Table 4 measured on other data (its CSV, committed), by the words naming that data: the
            recommended-rule line names the rule's worst ratio to CMA-ES over this run's and each of these.
        table6: Table 6's CSV (:func:`sdm.report.objects.table6`: this run's, or the committed snapshot), or None:
            the line on parameters attached to points.
        table7: Table 7's CSV (:func:`sdm.report.network.table7`: this run's, or the committed snapshot), or None:
            the line on SDM inside a network.
    """
    by_level = table2.set_index("level").sort_index()
    best = best_methods(table3, methods) if table3 is not None else None
    rule = recommended_rule(table4, rules) if table4 is not None else None
    rule_rows = table4[table4["flow"] == rule].set_index("level") if rule else None

    header = ["noise level (px)", "paper's Table 2 mean", "our Table 2 mean", "ours / paper's"]
    if best is not None:
        header.append("Table 3: closest method (its mean)")
    if rule_rows is not None:
        header.append(f"Table 4: rule `{rule}` (meets bar)")
    lines = ["| " + " | ".join(header) + " |", "|" + "---:|" * 4 + "---|" * (len(header) - 4)]
    for level, row in by_level.iterrows():
        cells = [str(int(level)), _mm(row["paper_mean"]), _mm(row["mean"]), _ratio(row["mean_ratio"])]
        if best is not None:
            chosen = best.loc[level] if level in best.index else None
            cells.append("" if chosen is None else f"{chosen['label']} ({_mm(1e3 * chosen['mean_m'])})")
        if rule_rows is not None:
            mine = rule_rows.loc[level] if level in rule_rows.index else None
            cells.append("" if mine is None else
                         f"{_mm(1e3 * mine['mean_m'])} ({'yes' if bool(mine['meets_bar']) else 'no'})")
        lines.append("| " + " | ".join(cells) + " |")
    out = ["Mean distance ||theta~ - theta*|| per noise level, 1e-3 m; every number is this run's "
           "([its tables](../tables/), [the full report](reproduction.md)).", "", *lines, "",
           f"![Our distances per noise level against the paper's mean and quartiles]({figure})", ""]
    out += [f"- **What reproduced:** {_reproduced(table1, table2)}",
            f"- **What did not:** {_not_reproduced(table1, table2)}"]
    if best is not None:
        out.append(f"- **Does SDM beat the alternatives?** {_against(table3, best)}")
    if table4 is not None:
        out.append(f"- **Recommended rule:** {_rule_sentence(table4, rule, data, elsewhere or {})}")
    if table6 is not None and len(table6):
        from .objects import verdict_sentence

        out.append(f"- **Parameters attached to points (Table 6):** {verdict_sentence(table6)}")
    if table7 is not None and len(table7):
        from .network import verdict_sentence as network_sentence

        out.append(f"- **SDM inside a network (Table 7):** {network_sentence(table7)}")
    return "\n".join(out) + "\n"


def _mm(value) -> str:
    return "" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{float(value):.3f}"


def _ratio(value) -> str:
    return "" if isinstance(value, float) and math.isnan(value) else f"{float(value):.2f}x"


def _noisy(table2: pd.DataFrame) -> pd.DataFrame:
    return table2[(table2["level"] > 0) & table2["level"].isin(list(paper.TABLE2))].sort_values("level")


def _reproduced(table1, table2) -> str:
    passed = [check for check in checks(table1, table2) if check.passed]
    if not passed:
        return "none of the acceptance criteria (the report's first table)."
    parts = []
    noise_free = [check for check in passed if "level 0" in check.name]
    if noise_free:
        parts.append(f"the noise-free mean, {noise_free[0].measured} (target: {noise_free[0].target})")
    noisy = _noisy(table2)
    within = noisy[(noisy["mean_ratio"] >= NOISY_RATIO[0]) & (noisy["mean_ratio"] <= NOISY_RATIO[1])]
    if len(within):
        parts.append(f"the noisy means at {_levels(within['level'])} within {NOISY_RATIO[0]:g}x-"
                     f"{NOISY_RATIO[1]:g}x of the paper's ({within['mean_ratio'].min():.2f}x-"
                     f"{within['mean_ratio'].max():.2f}x)")
    table1_check = [check for check in passed if check.name.startswith("Table 1")]
    if table1_check:
        parts.append(f"Table 1's pick ({table1_check[0].measured})")
    return "; ".join(parts) + "."


def _not_reproduced(table1, table2) -> str:
    parts = [f"{check.name}, {check.measured} (target: {check.target})"
             for check in checks(table1, table2) if not check.passed]
    noisy = _noisy(table2)
    larger = noisy[noisy["mean_ratio"] > 1]
    if len(larger):
        parts.append(f"the paper's noisy means themselves: ours are larger at {_levels(larger['level'])} "
                     f"({larger['mean_ratio'].min():.2f}x-{larger['mean_ratio'].max():.2f}x the paper's; the report's "
                     f"\"gaps\" section explains why)")
    return ("; ".join(parts) if parts else "nothing the report checks") + "."


def _against(table3: pd.DataFrame, best: pd.DataFrame) -> str:
    sdm_levels = [int(level) for level, row in best.iterrows() if row["method"] == "sdm"]
    others = best[best["method"] != "sdm"]
    if others.empty:
        return f"yes: SDM has the lowest mean distance of Table 3 at every noise level ({_levels(sdm_levels)})."
    sdm = table3[table3["method"] == "sdm"].set_index("level")["mean_m"]
    losses = []
    for label, rows in others.groupby("label", sort=False):
        worst = max(rows.index, key=lambda level: sdm.get(level, math.nan) / rows.loc[level, "mean_m"])
        losses.append(f"{label} is closer at {_levels(rows.index)}, by the most at level {int(worst)}: "
                      f"{_mm(1e3 * rows.loc[worst, 'mean_m'])} against SDM's {_mm(1e3 * sdm.get(worst, math.nan))}")
    head = "no, not everywhere" if sdm_levels else "no"
    won = f"; SDM is closest at {_levels(sdm_levels)}" if sdm_levels else ""
    return f"{head} (Table 3, the same noisy targets for every method): " + "; ".join(losses) + won + "."


def _rule_sentence(table4: pd.DataFrame, rule: str | None, data: str, elsewhere: Mapping[str, pd.DataFrame]) -> str:
    if rule is None:
        return "keep the paper's rule: no rule of Table 4 meets the bar (half the paper's mean) at any level."
    rows = table4[table4["flow"] == rule].sort_values("level")
    judged = rows[rows["bar_m"].notna()]
    ratios = rows.loc[rows["level"] > 0, "ratio_to_paper_rule"]
    moved = (f"; at the noisy levels its mean is {ratios.min():.2f}x-{ratios.max():.2f}x the paper's rule's on the "
             f"same draws" if len(ratios) else "")
    return (f"`{rule}` (Table 4): it meets the bar \"half the paper's mean\" (the paper's mean noise-free) at "
            f"{int(judged['meets_bar'].sum())} of {len(judged)} levels{moved}.{_against_cmaes(rule, data, table4, elsewhere)}")


def _against_cmaes(rule: str, data: str, table4: pd.DataFrame, elsewhere: Mapping[str, pd.DataFrame]) -> str:
    """The rule against CMA-ES on every data set its Table 4 was measured on: where its ratio to CMA-ES's mean
    (on the runs both have) is worst, and where it misses the bar of :data:`CMAES_FACTOR`; "" without CMA-ES."""
    worst, missed, measured = None, [], []
    for name, table in {data: table4, **elsewhere}.items():
        if "ratio_to_cmaes" not in table:
            continue
        rows = table[(table["flow"] == rule) & (table["cmaes_runs"] > 0)].sort_values("level")
        if rows.empty:
            continue
        measured.append(f"{name} ({', '.join(sorted({str(int(n)) for n in rows['cmaes_runs']}))} runs per level)")
        top = rows.loc[rows["ratio_to_cmaes"].idxmax()]
        if worst is None or top["ratio_to_cmaes"] > worst[1]["ratio_to_cmaes"]:
            worst = (name, top)
        over = rows[rows["ratio_to_cmaes"] > CMAES_FACTOR]
        if len(over):
            low, high = f"{over['ratio_to_cmaes'].min():.2f}x", f"{over['ratio_to_cmaes'].max():.2f}x"
            missed.append(f"on {name} at {_levels(over['level'])} ({low if low == high else f'{low}-{high}'})")
    if worst is None:
        return ""
    name, top = worst
    bar = (f"within {CMAES_FACTOR:g}x of CMA-ES at every level" if not missed
           else f"beyond {CMAES_FACTOR:g}x of CMA-ES " + " and ".join(missed))
    return (f" Measured on {' and on '.join(measured)}: its worst mean against CMA-ES's on the same runs is "
            f"{top['ratio_to_cmaes']:.2f}x, at level {int(top['level'])} on {name}; {bar}.")

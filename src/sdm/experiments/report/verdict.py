"""The verdict's facts (``results/report/verdict.json``): what a run's Tables 1-4 answer, as data.

Every number of the README's verdict comes from such facts: this run's (this module), Table 6's
(:func:`sdm.experiments.report.objects.verdict_facts`) and Table 7's (:func:`sdm.experiments.report.network.verdict_facts`). ``make
snapshot`` puts them into words, with the snapshot each one comes from (``workflow/scripts/verdict_text.py``): the
wording lives there, the numbers here. Distances are in millimetres (1e-3 m, the paper's Table 2 unit), ratios
plain numbers, levels the noise levels in pixels.

Only the methods and rules the run was configured with are compared (``methods``, ``rules``), so rows a table
may carry besides them (a reference row that is no method) never become "the closest method".
"""
from __future__ import annotations

import math
from typing import Mapping, Sequence

import pandas as pd

from .. import paper
from .reproduction import NOISE_FREE_MAX, NOISY_RATIO, checks
from .research import CMAES_FACTOR, CMAES_ROW

#: The black-box search the verdict sets SDM against (Table 3's method name).
SEARCH = "cmaes"


def best_methods(table3: pd.DataFrame, methods: Sequence[str]) -> pd.DataFrame:
    """Per noise level, the row of Table 3 (``method, label, level, mean_m``) with the lowest mean distance
    among ``methods`` (``sdm`` and the configured baselines)."""
    rows = table3[table3["method"].isin(list(methods))]
    return rows.loc[rows.groupby("noise_level")["mean_m"].idxmin()].set_index("noise_level")


def recommended_schedule(table4: pd.DataFrame, rules: Sequence[str]) -> str | None:
    """The rule of Table 4 among ``rules`` that meets the bar "half the paper's mean" at the most levels, ties
    broken by the lower mean distance over its levels; None when no rule meets the bar at any level (keep the
    paper's)."""
    rows = table4[table4["rule"].isin(list(rules))]
    if rows.empty:
        return None
    score = rows.groupby("rule", sort=False).agg(met=("meets_bar", "sum"), mean=("mean_m", "mean"))
    score = score.sort_values(["met", "mean"], ascending=[False, True], kind="stable")
    return None if score["met"].iloc[0] == 0 else str(score.index[0])


def _mm(metres) -> float | None:
    return None if metres is None or pd.isna(metres) else round(1e3 * float(metres), 6)


def reproduction_facts(table1: pd.DataFrame, table2: pd.DataFrame) -> dict:
    """Does the run reproduce the paper: the acceptance criteria of the report (``sdm.experiments.report.reproduction``) as
    data. ``verdict`` is ``"yes"`` when every criterion holds, ``"partly"`` when the noise-free one and at least one
    noisy one hold, ``"no"`` otherwise."""
    results = checks(table1, table2)
    by_level = table2.set_index("noise_level").sort_index()
    noisy = by_level[(by_level.index > 0) & by_level.index.isin(list(paper.TABLE2))]
    noise_free = next((check for check in results if "level 0" in check.name), None)
    noisy_passed = [check.passed for check in results if check.name.startswith("Table 2") and check is not noise_free]
    best = table1[table1["best"]].iloc[0]
    if all(check.passed for check in results):
        verdict = "yes"
    elif noise_free is not None and noise_free.passed and any(noisy_passed):
        verdict = "partly"
    else:
        verdict = "no"
    return {
        "verdict": verdict,
        "noise_free": None if 0 not in by_level.index else {
            "mm": float(by_level.loc[0, "mean"]), "paper_mm": float(by_level.loc[0, "paper_mean"]),
            "bar_mm": NOISE_FREE_MAX, "met": bool(noise_free.passed)},
        "noisy": None if noisy.empty else {
            "levels": [int(noise_level) for noise_level in noisy.index], "low": float(noisy["mean_ratio"].min()),
            "high": float(noisy["mean_ratio"].max()), "band": list(NOISY_RATIO), "within": all(noisy_passed)},
        "tuning": {"n_epoch": int(best["n_epoch"]), "lr": float(best["lr"]), "paper_n_epoch": paper.TABLE1_BEST[0],
                   "paper_lr": paper.TABLE1_BEST[1],
                   "same": bool(int(best["n_epoch"]) == paper.TABLE1_BEST[0]
                                and math.isclose(float(best["lr"]), paper.TABLE1_BEST[1]))},
    }


def search_rows(table3: pd.DataFrame | None, table4: pd.DataFrame | None) -> pd.DataFrame | None:
    """Per noise level, the black-box search's mean and SDM's (the paper's rule) on the same runs, in metres
    (``noise_level, search_m, sdm_m, runs``): Table 4's CMA-ES row where it has one (all CMA-ES runs, paired with Table
    2's), else Table 3's paired runs; None without CMA-ES."""
    if table4 is not None and (table4["rule"] == CMAES_ROW).any():
        rows = table4[table4["rule"] == CMAES_ROW]
        return pd.DataFrame({"noise_level": rows["noise_level"].astype(int), "search_m": rows["mean_m"],
                             "sdm_m": rows["paper_rule_mean_m"], "runs": rows["runs"].astype(int)})
    if table3 is None or not (table3["method"] == SEARCH).any():
        return None
    search = table3[table3["method"] == SEARCH].set_index("noise_level")
    sdm = table3[table3["method"] == "sdm"].set_index("noise_level")
    noise_levels = [noise_level for noise_level in search.index if noise_level in sdm.index]
    return pd.DataFrame({"noise_level": [int(noise_level) for noise_level in noise_levels], "search_m": search.loc[noise_levels, "mean_m"].values,
                         "sdm_m": sdm.loc[noise_levels, "mean_m"].values,
                         "runs": search.loc[noise_levels, "runs"].astype(int).values})


def search_facts(rows: pd.DataFrame | None, table3: pd.DataFrame | None) -> dict | None:
    """SDM (the paper's rule) against the black-box search on the same runs: the levels where each is closer, the
    level of the largest ratio, and each one's measured seconds per run (Table 3). ``verdict``: ``"yes"`` (SDM closer
    at every level), ``"partly"``, ``"no"``."""
    if rows is None or rows.empty:
        return None
    ratio = rows["sdm_m"] / rows["search_m"]
    worst = rows.loc[ratio.idxmax()]
    search_closer = [int(noise_level) for noise_level, r in zip(rows["noise_level"], ratio) if r > 1]
    seconds = {}
    if table3 is not None and "seconds_per_run" in table3:
        for method in ("sdm", SEARCH):
            values = table3.loc[table3["method"] == method, "seconds_per_run"]
            seconds[method] = float(values.mean()) if len(values) else None
    return {
        "method": SEARCH, "runs": int(rows["runs"].max()),
        "verdict": "no" if len(search_closer) == len(rows) else "partly" if search_closer else "yes",
        "search_closer_at": search_closer,
        "sdm_closer_at": [int(noise_level) for noise_level, r in zip(rows["noise_level"], ratio) if r <= 1],
        "worst": {"noise_level": int(worst["noise_level"]), "sdm_mm": _mm(worst["sdm_m"]), "search_mm": _mm(worst["search_m"]),
                  "ratio": float(ratio.max())},
        "seconds_per_run": seconds.get(SEARCH), "sdm_seconds_per_run": seconds.get("sdm"),
    }


def schedule_facts(table4: pd.DataFrame | None, rules: Sequence[str]) -> dict | None:
    """The recommended schedule of Table 4 (:func:`recommended_schedule`): the levels where it meets the bar "half the
    paper's mean", its mean over the paper's rule's on the same draws, and against CMA-ES on the runs both have
    (the bar: within :data:`sdm.experiments.report.research.CMAES_FACTOR` of CMA-ES's mean). None without Table 4; ``name`` None
    when no rule meets the bar anywhere."""
    if table4 is None:
        return None
    rule = recommended_schedule(table4, rules)
    if rule is None:
        return {"name": None}
    rows = table4[table4["rule"] == rule].sort_values("noise_level")
    judged = rows[rows["bar_m"].notna()]
    noisy = rows.loc[rows["noise_level"] > 0, "ratio_to_paper_rule"]
    facts = {"name": rule, "runs": int(rows["runs"].max()), "meets_bar": int(judged["meets_bar"].sum()),
             "judged": len(judged), "to_paper_rule": [float(noisy.min()), float(noisy.max())] if len(noisy) else None,
             "factor": CMAES_FACTOR, "to_search": None}
    if "ratio_to_cmaes" in rows and (rows["cmaes_runs"] > 0).any():
        paired = rows[rows["cmaes_runs"] > 0]
        worst = paired.loc[paired["ratio_to_cmaes"].idxmax()]
        facts["to_search"] = {
            "runs": int(paired["cmaes_runs"].max()), "low": float(paired["ratio_to_cmaes"].min()),
            "high": float(worst["ratio_to_cmaes"]), "worst_level": int(worst["noise_level"]),
            "beyond": [int(noise_level) for noise_level, r in zip(paired["noise_level"], paired["ratio_to_cmaes"]) if r > CMAES_FACTOR]}
    return facts


def level_rows(table2: pd.DataFrame, search: pd.DataFrame | None, table4: pd.DataFrame | None,
               rule: str | None) -> list[dict]:
    """The verdict's table, one row per noise level of Table 2 (millimetres): the paper's mean, ours (the paper's
    rule), the black-box search's and the recommended schedule's (None where the run has none)."""
    by_search = search.set_index("noise_level") if search is not None else None
    by_rule = table4[table4["rule"] == rule].set_index("noise_level") if rule else None
    out = []
    for _, row in table2.sort_values("noise_level").iterrows():
        noise_level = int(row["noise_level"])
        found = by_search is not None and noise_level in by_search.index
        mine = by_rule is not None and noise_level in by_rule.index
        out.append({"noise_level": noise_level, "paper_mm": float(row["paper_mean"]), "sdm_mm": float(row["mean"]),
                    "runs": int(row["runs"]) if "runs" in row else None,
                    "search_mm": _mm(by_search.loc[noise_level, "search_m"]) if found else None,
                    "schedule_mm": _mm(by_rule.loc[noise_level, "mean_m"]) if mine else None,
                    "schedule_meets_bar": bool(by_rule.loc[noise_level, "meets_bar"]) if mine else None})
    return out


def data_facts(config: Mapping, summary: Mapping) -> dict:
    """What a run's data is, for the verdict's caption: the source (``synthetic``, ``apollo``, ``pku``), the number of
    images (the data stage's ``summary.json``) and, for real data, its path (the config's)."""
    source = config["data"]["source"]
    data = {"source": source, "images": int(summary["images"])}
    if source != "synthetic":
        data["folder"] = config["data"]["apollo_folder" if source == "apollo" else "pku_csv"]
    return data


def facts(table1: pd.DataFrame, table2: pd.DataFrame, table3: pd.DataFrame | None = None,
          methods: Sequence[str] = (), table4: pd.DataFrame | None = None, rules: Sequence[str] = (),
          data: Mapping | None = None) -> dict:
    """The verdict's facts of one run (JSON-ready).

    Args:
        table1, table2: the CSVs of Tables 1 and 2 (:func:`sdm.experiments.report.tables.table1_frame`, ``table2_frame``;
            Table 2 in 1e-3 m).
        table3: Table 3's CSV (:func:`sdm.experiments.report.baselines.table3_frame`, metres), or None when it did not run;
            ``methods``: the methods compared in it (``sdm`` and the configured baselines).
        table4: Table 4's CSV (:func:`sdm.experiments.report.research.table4_frame`, metres), or None; ``rules``: the rules
            compared in it (the configured ones).
        data: what the run's data is (``source``, ``images``, ``folder`` for a real one), as the data stage's summary
            and the config give it.

    Returns:
        ``data``; ``levels`` (:func:`level_rows`); ``reproduction`` (:func:`reproduction_facts`); ``search``
        (:func:`search_facts`, None without CMA-ES); ``closest``: per level Table 3's closest configured method's
        label; ``schedule`` (:func:`schedule_facts`, None without Table 4).
    """
    search = search_rows(table3, table4)
    schedule = schedule_facts(table4, rules)
    closest = best_methods(table3, methods) if table3 is not None else None
    return {
        "data": dict(data or {}),
        "levels": level_rows(table2, search, table4, schedule["name"] if schedule else None),
        "reproduction": reproduction_facts(table1, table2),
        "search": search_facts(search, table3),
        "closest": None if closest is None else
        [{"noise_level": int(noise_level), "method": str(row["method"]), "label": str(row["label"]), "mm": _mm(row["mean_m"])}
         for noise_level, row in closest.iterrows()],
        "schedule": schedule,
    }

"""Table 6 and its figures: parameters attached to points (:mod:`sdm.objects`), gathered and put in words."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from ..objects import METHODS, REFERENCES
from .tables import TableFormat, write_table

#: Method labels, as the table and figures print them.
LABELS = {
    "sdm_paper": "SDM, the paper's rule",
    "sdm_schedule": "SDM, the recommended schedule",
    "cmaes": "CMA-ES per configuration",
    "cmaes_car": "CMA-ES per car (block sweeps)",
    "cmaes_reg": "CMA-ES, regularised toward its start",
    "silhouette": "soft silhouette",
    "floor": "floor (nearest minimiser)",
    "start": "do nothing: the shared start",
    "prior": "do nothing: theta*'s mean",
}
#: Table 6's rows per (sharing, level): the do-nothing references first, then the methods.
ROWS = REFERENCES + METHODS
#: The black-box peers SDM is compared with (the floor is a reference, not a peer).
PEERS = ("cmaes", "cmaes_car", "cmaes_reg", "silhouette")
#: The sharing levels in table order; "shared" is Table 2's runs.
SHARING_ORDER = ("shared", "configuration", "car", "camera+car")
#: How a unit reads per sharing level.
UNIT = {"shared": "the shared shift", "configuration": "a configuration's shift", "car": "a car's shift",
        "camera+car": "a car's camera + residual"}

TABLE6_FORMAT = TableFormat(
    columns=("sharing", "level", "method", "units", "hidden", "mean", "median", "q3", "start", "of_start", "closer",
             "cpu_ms"),
    headers={"sharing": "sharing", "level": "noise level", "method": "method", "units": "units scored",
             "hidden": "hidden cars", "mean": "mean", "median": "median", "q3": "Q3", "start": "its start's mean",
             "of_start": "x start", "closer": "closer than start", "cpu_ms": "CPU ms / config"},
    formats={"mean": ".2f", "median": ".2f", "q3": ".2f", "start": ".2f", "of_start": ".2f", "closer": ".2f",
             "cpu_ms": ".2f"},
    caption="Table 6: parameters attached to points, distance per unit to theta* (1e-3 m) and CPU time",
    label="tab:table6",
    notes=(
        "A unit is what a configuration's pixels identify: its shift (a shift per configuration), a car's shift (per "
        "car), or a car's camera + residual total. Distances ||theta~_k - theta*_k|| over every scored unit of the "
        "paired runs.",
        "Hidden cars own no point of E': they have no row, nothing pulls them, and they are left out of every "
        "statistic (their count over the runs is given).",
        "The shared level is Table 2's runs (the paper's rule), quoted; its CPU time is not measured here.",
        "CPU ms per configuration: a run's process time over its configurations; the shared start of SDM, CMA-ES "
        "and the silhouette is counted in each.",
        "Doing nothing: the shared start (the paper's rule on one shift; SDM's paper-rule rows, CMA-ES and the "
        "silhouette start there) and theta*'s mean (no pixel looked at). Its start's mean: the mean distance of the "
        "start the method was given, on the same units (the shared start for the floor, which is given theta*). "
        "x start: the method's mean over that (paired); closer than start: the share of units it ends closer.",
    ),
)


def table6(run_frames: Sequence[pd.DataFrame], table2_distances: pd.DataFrame | None = None) -> pd.DataFrame:
    """Table 6 from :func:`sdm.objects.objects_runs`' frames and Table 2's per-run distances.

    Returns:
        One row per (sharing, noise level, method): ``units`` scored, ``hidden`` cars over the runs, the mean,
        median and Q3 distance (metres) and CPU milliseconds per configuration.
    """
    rows = []
    if table2_distances is not None and len(table2_distances):
        for level, group in table2_distances.groupby("level", sort=True):
            d = group["distance"].to_numpy(dtype=float)
            rows.append(_row("shared", int(level), "sdm_paper", d, 0, math.nan))
    frame = pd.concat(run_frames, ignore_index=True) if run_frames else pd.DataFrame()
    for (sharing, level), group in (frame.groupby(["sharing", "level"], sort=False) if len(frame) else []):
        hidden = int(group.loc[group["method"] == "hidden", "unit"].sum())
        for method in ROWS:
            own = group[group["method"] == method]
            if len(own):
                per_run = own.groupby("run")["cpu_s"].first()
                rows.append(_row(sharing, int(level), method, own["distance"].to_numpy(dtype=float), hidden,
                                 1000 * float(per_run.mean()), own["start"].to_numpy(dtype=float)))
    table = pd.DataFrame(rows, columns=["sharing", "level", "method", "units", "hidden", "mean_m", "median_m", "q3_m",
                                        "start_m", "of_start", "closer", "cpu_ms"])
    order = {name: i for i, name in enumerate(SHARING_ORDER)}
    methods = {name: i for i, name in enumerate(ROWS)}
    return table.sort_values(["sharing", "level", "method"], key=lambda c: c.map(order) if c.name == "sharing"
                             else c.map(methods) if c.name == "method" else c, kind="stable").reset_index(drop=True)


def _row(sharing, level, method, distances: np.ndarray, hidden: int, cpu_ms: float,
         start: np.ndarray | None = None) -> dict:
    """One row; ``start``: the distances of the method's start on the same units (paired), or None (Table 2's)."""
    paired = start is not None and start.size and float(start.mean()) > 0
    return {"sharing": sharing, "level": level, "method": method, "units": int(distances.size), "hidden": hidden,
            "mean_m": float(distances.mean()), "median_m": float(np.median(distances)),
            "q3_m": float(np.quantile(distances, 0.75)),
            "start_m": float(start.mean()) if start is not None and start.size else math.nan,
            "of_start": float(distances.mean() / start.mean()) if paired else math.nan,
            "closer": float((distances < start).mean()) if paired else math.nan, "cpu_ms": cpu_ms}


def against_cmaes(table: pd.DataFrame, sharing: str) -> list[tuple[int, str, float, float]]:
    """Per noise level of ``sharing``: ``(level, rule, ratio, speed)``, SDM's closer rule (the lower mean of the two),
    its mean over CMA-ES's and CMA-ES's CPU time over its own; levels without CMA-ES or SDM are left out."""
    out = []
    for level, group in table[table["sharing"] == sharing].groupby("level", sort=True):
        by = group.set_index("method")
        rules = [m for m in ("sdm_paper", "sdm_schedule") if m in by.index]
        if "cmaes" not in by.index or not rules:
            continue
        best = min(rules, key=lambda m: by.loc[m, "mean_m"])
        out.append((int(level), best, by.loc[best, "mean_m"] / by.loc["cmaes", "mean_m"],
                    by.loc["cmaes", "cpu_ms"] / by.loc[best, "cpu_ms"]))
    return out


def against_start(table: pd.DataFrame, sharing: str) -> list[dict]:
    """Per noise level of ``sharing``, in terms of doing nothing: SDM's closer rule and the best peer (:data:`PEERS`,
    the lower mean), each with the share of its start's error it removes (``1 - x start``, paired on the same units)
    and the share of units it ends closer than its start, and the peer's CPU time over SDM's. Needs the reference
    columns (``of_start``); levels without SDM are left out."""
    out = []
    for level, group in table[table["sharing"] == sharing].groupby("level", sort=True):
        by = group.set_index("method")
        rules = [m for m in ("sdm_paper", "sdm_schedule") if m in by.index]
        if not rules:
            continue
        best = min(rules, key=lambda m: by.loc[m, "mean_m"])
        peers = [m for m in PEERS if m in by.index]
        peer = min(peers, key=lambda m: by.loc[m, "mean_m"]) if peers else None
        row = {"level": int(level), "rule": best, "removed": 1 - float(by.loc[best, "of_start"]),
               "closer": float(by.loc[best, "closer"]), "start_m": float(by.loc[best, "start_m"]),
               "prior_m": float(by.loc["prior", "mean_m"]) if "prior" in by.index else math.nan,
               "peer": peer}
        if peer is not None:
            row |= {"peer_removed": 1 - float(by.loc[peer, "of_start"]), "peer_closer": float(by.loc[peer, "closer"]),
                    "speed": float(by.loc[peer, "cpu_ms"] / by.loc[best, "cpu_ms"]),
                    "ratio": float(by.loc[best, "mean_m"] / by.loc[peer, "mean_m"])}
        out.append(row)
    return out


def _removed_words(row: dict) -> str:
    """One level in words: the share of the start's error SDM removes, the best peer's, the CPU ratio."""
    words = (f"level {row['level']}: SDM ({LABELS[row['rule']]}) removes {100 * row['removed']:.0f} % of its start's "
             f"error ({100 * row['closer']:.0f} % of units end closer)")
    if row["peer"] is not None:
        worse = " (worse than doing nothing)" if row["peer_removed"] < 0 else ""
        words += (f", the best peer ({LABELS[row['peer']]}) {100 * row['peer_removed']:.0f} %{worse} at "
                  f"{row['speed']:.0f}x SDM's CPU time")
    return words


def verdict_sentence(table: pd.DataFrame) -> str:
    """Table 6 in one sentence for the verdict: per sharing level, SDM's best rule's mean against CMA-ES's over
    the noise levels (the range of the ratio) and how much less CPU time it takes per configuration; in terms of
    doing nothing where the table has its references (the share of the start's error SDM and the best peer
    remove)."""
    if "of_start" in table.columns:
        parts = []
        for sharing in SHARING_ORDER[1:]:
            rows = against_start(table, sharing)
            if rows:
                parts.append(f"with {UNIT[sharing]} unknown, " + "; ".join(_removed_words(row) for row in rows))
        return ("; ".join(parts) + " (docs/results/objects/).") if parts else "no sharing level was run."
    parts = []
    for sharing in SHARING_ORDER[1:]:
        compared = against_cmaes(table, sharing)
        ratios, speeds = [ratio for *_, ratio, _ in compared], [speed for *_, speed in compared]
        if ratios:
            levels = sorted(set(table.loc[table["sharing"] == sharing, "level"]))
            span = f"{min(ratios):.2f}-{max(ratios):.2f}x" if len(ratios) > 1 else f"{ratios[0]:.2f}x"
            parts.append(f"with {UNIT[sharing]} unknown, SDM's closer rule ends at {span} CMA-ES's mean distance "
                         f"(noise levels {levels[0]}-{levels[-1]}) at 1/{min(speeds):.0f} to 1/{max(speeds):.0f} of "
                         f"its CPU time per configuration")
    if not parts:
        return "no sharing level was run."
    return "; ".join(parts) + " (docs/results/objects/)."


def write_table6(frame: pd.DataFrame, stem: str | Path) -> list[Path]:
    """Table 6's CSV (metres), Markdown, LaTeX and HTML (1e-3 m)."""
    shown = frame.assign(mean=1e3 * frame["mean_m"], median=1e3 * frame["median_m"], q3=1e3 * frame["q3_m"],
                         start=1e3 * frame["start_m"], method=frame["method"].map(LABELS))
    return write_table(frame, stem, TABLE6_FORMAT, shown)


def scaling_table(frames: Sequence[pd.DataFrame]) -> pd.DataFrame:
    """Per (cars, method, budget): the mean over runs of the run's mean and median distance, its start's mean
    distance on the same cars, the share of cars ending closer than the start, and CPU s per config."""
    frame = pd.concat(frames, ignore_index=True)
    columns = [c for c in ("mean", "median", "start", "closer", "cpu_s") if c in frame.columns]
    return frame.groupby(["cars", "method", "budget"], sort=True)[columns].mean().reset_index()


def _bar(met: bool) -> str:
    return "met" if met else "missed"


def table6_summary(table: pd.DataFrame, scaling: pd.DataFrame | None) -> str:
    """Table 6 in plain words (Markdown): per sharing level and noise level, the share of its start's error that
    SDM and the best peer remove and their CPU time ratio; the bars of the car level; the scaling against doing
    nothing."""
    lines = ["## Table 6 in words", ""]
    for sharing in SHARING_ORDER[1:]:
        rows = table[table["sharing"] == sharing]
        if not len(rows):
            continue
        hidden = int(rows["hidden"].max())
        lines.append(f"- **{UNIT[sharing].capitalize()}** ({hidden} hidden cars over the runs, left out): "
                     + "; ".join(_removed_words(row) for row in against_start(table, sharing)) + ".")
    car = table[table["sharing"] == "car"].set_index(["level", "method"])
    if ("sdm_schedule" in set(car.index.get_level_values(1))) and 0 in set(car.index.get_level_values(0)):
        lines += [""]
        for level, bar in ((0, 0.2), (2, 0.5)):
            if (level, "sdm_schedule") in car.index:
                row = car.loc[(level, "sdm_schedule")]
                lines.append(f"- Car level, noise {level}: the recommended schedule ends at {row['of_start']:.2f}x "
                             f"its start's mean distance ({1e3 * row['mean_m']:.1f} against "
                             f"{1e3 * row['start_m']:.1f}e-3 m); at most {bar}x: {_bar(row['of_start'] <= bar)}.")
        floors = table[(table["method"] == "floor") & (table["level"] == 0)]
        if len(floors):
            worst = floors.loc[floors["of_start"].idxmax()]
            lines.append(f"- The floor without noise: at most {worst['of_start']:.3f}x the start's error over the "
                         f"sharing levels (worst: {worst['sharing']}); at most 0.05x: "
                         f"{_bar(worst['of_start'] <= 0.05)}.")
        worse = table[(table["level"] == 0) & table["method"].isin(METHODS) & (table["of_start"] > 1)]
        lines.append("- Without noise, every method ends closer than its start on average." if not len(worse) else
                     "- Without noise, these end farther than their start on average: " + "; ".join(
                         f"{LABELS[r['method']]} ({r['sharing']}, {r['of_start']:.2f}x)" for _, r in worse.iterrows())
                     + ".")
    if scaling is not None and len(scaling):
        lines += ["", "**Scaling with the number of cars per image** (one shift per car, error against CPU time per "
                  "configuration; x start: the mean over the shared start's mean on the same cars):", ""]
        for cars, group in scaling.groupby("cars", sort=True):
            sdm = group[group["method"] == "sdm_paper"]
            cma = group[group["method"].isin(["cmaes", "cmaes_car"])]  # the best peer: joint or per car
            if not len(sdm) or not len(cma):
                continue
            best_sdm, best_cma = sdm.loc[sdm["mean"].idxmin()], cma.loc[cma["mean"].idxmin()]
            peer = LABELS[best_cma["method"]]
            start = float(best_sdm["start"]) if "start" in group.columns else math.nan
            prior = group.loc[group["method"] == "prior", "mean"]
            line = (f"- K = {cars} ({2 * cars} unknowns): doing nothing {1e3 * start:.1f}e-3 m (the shared start)"
                    + (f", {1e3 * float(prior.iloc[0]):.1f}e-3 m (theta*'s mean)" if len(prior) else "")
                    + f"; SDM's best {best_sdm['mean'] / start:.2f}x start at {1e3 * best_sdm['cpu_s']:.2f} ms, "
                    f"the best peer's ({peer}, budget {int(best_cma['budget'])}) {best_cma['mean'] / start:.2f}x start "
                    f"at {1e3 * best_cma['cpu_s']:.1f} ms per configuration.")
            if cars >= 8:
                if best_cma["mean"] > start:
                    line += " The best peer ends farther than doing nothing here: no ratio to it is a comparison."
                else:
                    within = best_sdm["mean"] <= 1.5 * best_cma["mean"]
                    cheap = best_sdm["cpu_s"] <= best_cma["cpu_s"] / 10
                    line += (f" Within 1.5x of the best peer's mean at no more than 1/10 of its time: "
                             f"{_bar(within and cheap)} ({best_sdm['mean'] / best_cma['mean']:.2f}x its mean, "
                             f"{best_cma['cpu_s'] / best_sdm['cpu_s']:.0f}x less time).")
            lines.append(line)
    return "\n".join(lines) + "\n"


def plot_table6(table: pd.DataFrame, path: str | Path) -> Path:
    """Mean distance per unit against the noise level, one panel per sharing level, one line per method."""
    from .figures import plt, save_figure

    sharings = [s for s in SHARING_ORDER if s in set(table["sharing"])]
    fig, axes = plt.subplots(1, len(sharings), figsize=(4 * len(sharings), 3.4), sharey=False, squeeze=False)
    for ax, sharing in zip(axes[0], sharings):
        rows = table[table["sharing"] == sharing]
        for method in ROWS:
            own = rows[rows["method"] == method].sort_values("level")
            if len(own):
                ax.plot(own["level"], 1e3 * own["mean_m"], marker="." if method in REFERENCES else "o",
                        linestyle=":" if method in REFERENCES else "-", color="grey" if method == "prior" else None,
                        label=LABELS[method])
        ax.set_title(UNIT[sharing])
        ax.set_xlabel("noise level (pixels)")
        ax.set_yscale("log")
    axes[0][0].set_ylabel("mean distance per unit (1e-3 m)")
    axes[0][-1].legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_scaling(scaling: pd.DataFrame, path: str | Path) -> Path:
    """Mean distance per car against CPU seconds per configuration: one curve per K and method."""
    from .figures import plt, save_figure

    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    cars = sorted(set(scaling["cars"]))
    colours = plt.cm.viridis(np.linspace(0, 0.9, max(len(cars), 1)))
    for colour, k in zip(colours, cars):
        for method, style, name in (("sdm_paper", "-o", "SDM"), ("cmaes", "--s", "CMA-ES"),
                                    ("cmaes_car", "-.^", "CMA-ES per car")):
            own = scaling[(scaling["cars"] == k) & (scaling["method"] == method)].sort_values("cpu_s")
            if len(own):
                ax.plot(own["cpu_s"], 1e3 * own["mean"], style, color=colour, markersize=4, label=f"K = {k}, {name}")
        start = scaling[(scaling["cars"] == k) & (scaling["method"] == "start")]
        if len(start):
            ax.axhline(1e3 * float(start["mean"].iloc[0]), color=colour, linestyle=":", linewidth=0.8)
    ax.set_xscale("log")
    ax.set_xlabel("CPU seconds per configuration")
    ax.set_ylabel("mean distance per car (1e-3 m)")
    ax.set_title("One shift per car: SDM (solid), CMA-ES (dashed, per car dash-dot), doing nothing (dotted)")
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    return save_figure(fig, path)


"""Table 6 and its figures: parameters attached to points (:mod:`sdm.experiments.objects`), gathered and put in words."""
from __future__ import annotations

import gzip
import io
import itertools
import math
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from ..objects import EXACT_SET, METHODS, REFERENCES
from .tables import TableFormat, write_table

#: Method labels, as the table and figures print them.
LABELS = {
    "sdm_paper": "SDM, the paper's rule",
    "sdm_schedule": "SDM, the recommended schedule",
    "cmaes": "CMA-ES per configuration",
    "cmaes_car": "CMA-ES per unit (block sweeps)",
    "cmaes_reg": "CMA-ES, regularised toward its start",
    "silhouette": "soft silhouette",
    "floor": "floor (nearest minimiser)",
    "start": "do nothing: the shared start",
    "prior": "do nothing: theta*'s mean",
    EXACT_SET: "any point of the exact-match set",
}
#: Table 6's rows per (scale, sharing, level): the do-nothing references first, what the pixels identify, the methods.
ROWS = REFERENCES + (EXACT_SET,) + METHODS
#: SDM's rows, each a row of the table; the summaries speak of the one with the lower mean.
SDM_METHODS = ("sdm_paper", "sdm_schedule")
#: The black-box peers SDM is compared with (the floor is a reference, not a peer).
PEERS = ("cmaes", "cmaes_car", "cmaes_reg", "silhouette")
#: The sharing levels in table order; "shared" is Table 2's runs.
SHARING_ORDER = ("shared", "configuration", "car", "camera+car")
#: How a unit reads per sharing level.
UNIT = {"shared": "the shared shift", "configuration": "a configuration's shift", "car": "a car's shift",
        "camera+car": "a car's camera + residual"}

TABLE6_FORMAT = TableFormat(
    columns=("scale", "sharing", "noise_level", "method", "units", "hidden", "mean", "median", "q3", "start", "of_start",
             "closer", "gated", "gated_of_start", "extent_a", "extent_b", "cpu_ms"),
    headers={"scale": "screen scale", "sharing": "sharing", "noise_level": "noise level", "method": "method",
             "units": "units scored", "hidden": "hidden cars", "mean": "mean", "median": "median", "q3": "Q3",
             "start": "its start's mean", "of_start": "x start", "closer": "closer than start",
             "gated": "mean, gated", "gated_of_start": "x start, gated",
             "extent_a": "exact set a", "extent_b": "exact set b", "cpu_ms": "CPU ms / config"},
    formats={"mean": ".2f", "median": ".2f", "q3": ".2f", "start": ".2f", "of_start": ".2f", "closer": ".2f",
             "gated": ".2f", "gated_of_start": ".2f",
             "extent_a": ".1f", "extent_b": ".1f", "cpu_ms": ".2f"},
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
        "Screen scale: the screen is scale times the Sky screen's 128 x 256 (the paper's case is 1). Exact set a, b: "
        "the median over the units of the first run of each job of the extent per axis of the set of shifts that "
        "reproduce the unit's noise-free target exactly (1e-3 m): what its pixels identify. The row 'any point of "
        "the exact-match set' is the mean distance from theta* of a point of that set.",
        "Gated: the method's estimates after the prior gate (docs/method/objects.md, 'The prior gate'): a unit that "
        "ends farther from the method's start than research.objects.gate standard deviations of its prior is "
        "returned to that start. Scored where a unit is one row (a configuration's or a car's shift).",
    ),
)


def table6(run_frames: Sequence[pd.DataFrame], table2_distances: pd.DataFrame | None = None) -> pd.DataFrame:
    """Table 6 from :func:`sdm.experiments.objects.objects_runs`' frames and Table 2's per-run distances.

    A frame without a ``scale`` column is of scale 1 (the Sky screen); Table 2's runs are the shared level there.

    Returns:
        One row per (scale, sharing, noise level, method): ``units`` scored, ``hidden`` cars over the runs, the mean,
        median and Q3 distance (metres), the start's mean on the same units, the paired fraction ``of_start`` and the
        share ``closer`` than the start, the median exact-match extent per axis ``extent_a_m``, ``extent_b_m``
        (metres, over the :data:`sdm.experiments.objects.EXACT_SET` units of the group; NaN where none was scanned) and CPU
        milliseconds per configuration. Scales in their order in the frames (the first screen first).
    """
    rows = []
    frame = pd.concat(run_frames, ignore_index=True) if run_frames else pd.DataFrame()
    if len(frame) and "scale" not in frame.columns:
        frame = frame.assign(scale=1)
    scales = list(dict.fromkeys(int(v) for v in frame["scale"])) if len(frame) else []
    if table2_distances is not None and len(table2_distances):
        for noise_level, group in table2_distances.groupby("noise_level", sort=True):
            d = group["distance"].to_numpy(dtype=float)
            rows.append(_row(1, "shared", int(noise_level), "sdm_paper", d, 0, math.nan))
        scales = scales if 1 in scales else scales + [1]
    for (scale, sharing, noise_level), group in (frame.groupby(["scale", "sharing", "noise_level"], sort=False)
                                           if len(frame) else []):
        hidden = int(group.loc[group["method"] == "hidden", "unit"].sum())
        sets = group[group["method"] == EXACT_SET]
        extent = ((float(sets["extent_a"].median()), float(sets["extent_b"].median())) if len(sets)
                  else (math.nan, math.nan))
        for method in ROWS:
            own = group[group["method"] == method]
            if len(own):
                per_run = own.groupby("run")["cpu_s"].first()
                gated = own["gated"].to_numpy(dtype=float) if "gated" in own.columns else None
                rows.append(_row(int(scale), sharing, int(noise_level), method, own["distance"].to_numpy(dtype=float),
                                 hidden, 1000 * float(per_run.mean()), own["start"].to_numpy(dtype=float), extent,
                                 gated))
    table = pd.DataFrame(rows, columns=["scale", "sharing", "noise_level", "method", "units", "hidden", "mean_m", "median_m",
                                        "q3_m", "start_m", "of_start", "closer", "gated_m", "gated_median_m",
                                        "gated_of_start", "gated_closer", "extent_a_m", "extent_b_m", "cpu_ms"])
    order = {name: i for i, name in enumerate(SHARING_ORDER)}
    methods = {name: i for i, name in enumerate(ROWS)}
    screens = {scale: i for i, scale in enumerate(scales)}
    keys = {"scale": screens, "sharing": order, "method": methods}
    return table.sort_values(["scale", "sharing", "noise_level", "method"],
                             key=lambda c: c.map(keys[c.name]) if c.name in keys else c,
                             kind="stable").reset_index(drop=True)


def _row(scale, sharing, noise_level, method, distances: np.ndarray, hidden: int, cpu_ms: float,
         start: np.ndarray | None = None, extent: tuple[float, float] = (math.nan, math.nan),
         gated: np.ndarray | None = None) -> dict:
    """One row; ``start``: the distances of the method's start on the same units (paired), or None (Table 2's);
    ``gated``: the distances after the prior gate (NaN where it is not scored), or None."""
    paired = start is not None and start.size and float(start.mean()) > 0
    scored = paired and gated is not None and gated.size and not np.isnan(gated).any()
    nan = math.nan
    return {"gated_m": float(gated.mean()) if scored else nan,
            "gated_median_m": float(np.median(gated)) if scored else nan,
            "gated_of_start": float(gated.mean() / start.mean()) if scored else nan,
            "gated_closer": float((gated < start).mean()) if scored else nan,
            "scale": scale, "sharing": sharing, "noise_level": noise_level, "method": method, "units": int(distances.size),
            "hidden": hidden, "mean_m": float(distances.mean()), "median_m": float(np.median(distances)),
            "q3_m": float(np.quantile(distances, 0.75)),
            "start_m": float(start.mean()) if start is not None and start.size else math.nan,
            "of_start": float(distances.mean() / start.mean()) if paired else math.nan,
            "closer": float((distances < start).mean()) if paired else math.nan,
            "extent_a_m": extent[0], "extent_b_m": extent[1], "cpu_ms": cpu_ms}


def units_archive(run_frames: Sequence[pd.DataFrame], scaling_frames: Sequence[pd.DataFrame] = ()) -> bytes:
    """Every per-unit record of Table 6's runs and every record of the scaling, as one gzip-compressed CSV (bytes;
    no time stamp, so the same records give the same bytes).

    Columns: those of :data:`sdm.experiments.objects.RUN_COLUMNS` with ``scale`` first, and ``table`` (``runs`` or ``scaling``)
    before them; a scaling record keeps its own columns (:data:`sdm.experiments.objects.SCALING_COLUMNS`), empty elsewhere.
    Numbers with 7 significant digits (distances to 1e-7 m at most).
    """
    parts = [frame.assign(table="runs") for frame in run_frames]
    parts += [frame.assign(table="scaling") for frame in scaling_frames]
    frame = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=["table"])
    frame = frame[["table"] + [c for c in frame.columns if c != "table"]]
    text = frame.to_csv(index=False, float_format="%.7g", lineterminator="\n")
    return gzip.compress(text.encode(), compresslevel=9, mtime=0)


def read_units_archive(path: str | Path) -> pd.DataFrame:
    """The records :func:`units_archive` wrote to ``path``."""
    return pd.read_csv(io.BytesIO(gzip.decompress(Path(path).read_bytes())), low_memory=False)


def _scales(table: pd.DataFrame) -> list[int]:
    """The table's screen scales in its order (the chosen screen first); a table without them is of scale 1."""
    return list(dict.fromkeys(int(v) for v in table["scale"])) if "scale" in table.columns else [1]


def _of_scale(table: pd.DataFrame, scale: int, sharing: str) -> pd.DataFrame:
    rows = table[table["sharing"] == sharing]
    return rows[rows["scale"] == scale] if "scale" in table.columns else rows


def against_start(table: pd.DataFrame, sharing: str, scale: int = 1, gated: bool = False) -> list[dict]:
    """Per noise level of ``sharing`` on the screen of ``scale``, in terms of doing nothing: SDM's closer rule and the
    best peer (:data:`PEERS`, the lower mean), each with the share of its start's error it removes (``1 - x start``,
    paired on the same units) and the share of units it ends closer than its start, and the peer's CPU time over
    SDM's. With ``gated``, every method's estimates after the prior gate (the ``gated_*`` columns; levels where the
    gate is not scored are left out). Needs the reference columns (``of_start``); levels without SDM are left out."""
    mean, of_start, closer = ("gated_m", "gated_of_start", "gated_closer") if gated else ("mean_m", "of_start",
                                                                                        "closer")
    out = []
    for noise_level, group in _of_scale(table, scale, sharing).groupby("noise_level", sort=True):
        by = group.set_index("method")
        if mean not in by.columns:
            continue
        rules = [m for m in SDM_METHODS if m in by.index and not math.isnan(by.loc[m, mean])]
        if not rules:
            continue
        best = min(rules, key=lambda m: by.loc[m, mean])
        peers = [m for m in PEERS if m in by.index and not math.isnan(by.loc[m, mean])]
        peer = min(peers, key=lambda m: by.loc[m, mean]) if peers else None
        row = {"noise_level": int(noise_level), "rule": best, "gated": gated, "removed": 1 - float(by.loc[best, of_start]),
               "closer": float(by.loc[best, closer]), "start_m": float(by.loc[best, "start_m"]),
               "prior_m": float(by.loc["prior", "mean_m"]) if "prior" in by.index else math.nan,
               "extent": (float(by.loc[best, "extent_a_m"]), float(by.loc[best, "extent_b_m"]))
               if "extent_a_m" in by.columns else (math.nan, math.nan),
               "peer": peer}
        if peer is not None:
            row |= {"peer_removed": 1 - float(by.loc[peer, of_start]), "peer_closer": float(by.loc[peer, closer]),
                    "speed": float(by.loc[peer, "cpu_ms"] / by.loc[best, "cpu_ms"]),
                    "ratio": float(by.loc[best, mean] / by.loc[peer, mean])}
        out.append(row)
    return out


def _removed_words(row: dict) -> str:
    """One level in words: the share of the start's error SDM removes, the best peer's, the CPU ratio."""
    words = (f"level {row['noise_level']}: {LABELS[row['rule']]} removes {100 * row['removed']:.0f} % of its start's "
             f"error ({100 * row['closer']:.0f} % of units end closer)")
    if row["peer"] is not None:
        removed = (f"{100 * row['peer_removed']:.0f} %" if row["peer_removed"] >= 0 else
                   f"none: it ends {100 * -row['peer_removed']:.0f} % farther than its start (worse than doing nothing)")
        words += f", the best peer ({LABELS[row['peer']]}) {removed}, at {row['speed']:.0f}x SDM's CPU time"
    return words


def screen_words(scale: int) -> str:
    return f"on the screen of scale {scale} ({128 * scale} x {256 * scale}{', the paper' + chr(39) + 's' if scale == 1 else ''})"


def verdict_facts(table: pd.DataFrame) -> dict:
    """Table 6 for the verdict, as data (``results/tables/table6_verdict.json``): per screen scale, sharing level and
    noise level, SDM's closer rule and the best peer against doing nothing (:func:`against_start`: the share of the
    start's error each removes, the share of units SDM ends closer, the peer's CPU time over SDM's), every method
    with the prior gate where it is scored (``gated``), as it is otherwise. The screens in the table's order (the
    chosen one first); no rows for a table without the reference columns."""
    rows = []
    if "of_start" in table.columns:
        for scale in _scales(table):
            for sharing in SHARING_ORDER[1:]:
                compared = against_start(table, sharing, scale, gated=True) or against_start(table, sharing, scale)
                for row in compared:
                    peer, gate = row["peer"], " with the prior gate" if row["gated"] else ""
                    rows.append({"scale": int(scale), "screen": [128 * int(scale), 256 * int(scale)],
                                 "sharing": sharing, "noise_level": row["noise_level"], "rule": row["rule"],
                                 "gated": row["gated"], "rule_label": LABELS[row["rule"]] + gate,
                                 "removed": row["removed"], "closer": row["closer"], "peer": peer,
                                 "peer_label": LABELS[peer] + gate if peer else None,
                                 "peer_removed": row.get("peer_removed"), "cpu_ratio": row.get("speed")})
    return {"scales": _scales(table), "rows": rows}


def write_table6(frame: pd.DataFrame, stem: str | Path) -> list[Path]:
    """Table 6's CSV (metres), Markdown, LaTeX and HTML (1e-3 m)."""
    shown = frame.assign(mean=1e3 * frame["mean_m"], median=1e3 * frame["median_m"], q3=1e3 * frame["q3_m"],
                         start=1e3 * frame["start_m"], method=frame["method"].map(LABELS),
                         gated=1e3 * frame["gated_m"])
    if "extent_a_m" in frame.columns:
        shown = shown.assign(extent_a=1e3 * frame["extent_a_m"], extent_b=1e3 * frame["extent_b_m"])
    return write_table(frame, stem, TABLE6_FORMAT, shown)


def bar_word(met: bool) -> str:
    return "met" if met else "missed"


def in_mm(value: float) -> str:
    return f"{1e3 * value:.1f}e-3 m"


#: A car ends far from theta* beyond this distance (metres): the tail that the car level's mean is made of.
FAR_M = 0.1


def tail_words(run_frames: Sequence[pd.DataFrame], scale: int, method: str = "sdm_schedule",
               worst: int = 3, gated: bool = False) -> list[str]:
    """Where the car level's mean distance of ``method`` comes from on the screen of ``scale``, per noise level:
    the runs' configurations and distinct cars (every run draws the same configurations, each with its own theta*
    and start), the share of the cars' runs that end farther than :data:`FAR_M` and their share of the summed
    distance, and the share the ``worst`` cars (by their mean over the runs) make. With ``gated``, of its estimates
    after the prior gate (record column ``gated``), with the share of the cars' runs the gate returned to their
    start and theirs of the summed distance. ``run_frames``: the per-unit records of
    :func:`sdm.experiments.objects.objects_runs` (a ``scale`` column, or scale 1 without one)."""
    frames = [frame for frame in run_frames if len(frame)]
    if not frames:
        return []
    units = pd.concat(frames, ignore_index=True)
    on_screen = units["scale"] == scale if "scale" in units.columns else pd.Series(scale == 1, index=units.index)
    rows = units[on_screen & (units["sharing"] == "car") & (units["method"] == method)]
    column = "gated" if gated else "distance"
    if column not in rows.columns:
        return []
    lines = []
    for noise_level, own in rows.groupby("noise_level", sort=True):
        total = float(own[column].sum())
        if not total > 0:
            continue
        far = own[column] > FAR_M
        cars = own.groupby(["config", "car"])[column]
        top = cars.mean().nlargest(worst).index
        top_far = cars.apply(lambda d: (d > FAR_M).mean()).loc[top]
        top_share = float(cars.sum().loc[top].sum()) / total
        name = LABELS[method].removeprefix("SDM, ") + (" with the prior gate" if gated else "")
        words = (
            f"- Car level, noise {int(noise_level)}, {name}, where the mean comes from: {own['run'].nunique()} runs of the "
            f"same {own['config'].nunique()} configurations ({cars.ngroups} cars, each run with its own theta* and "
            f"start); {100 * far.mean():.0f} % of the cars' runs end farther than {FAR_M:g} m from theta* and make "
            f"{100 * own.loc[far, column].sum() / total:.0f} % of the summed distance; the {len(top)} cars with the "
            f"largest mean make {100 * top_share:.0f} % of it, each ending that far in "
            f"{100 * top_far.min():.0f}-{100 * top_far.max():.0f} % of its runs")
        if gated:
            returned = own["gated"] != own["distance"]
            words += (f"; the gate returned {100 * returned.mean():.1f} % of the cars' runs to their start, "
                      f"{100 * own.loc[returned, 'gated'].sum() / total:.0f} % of the summed distance")
        lines.append(words + ".")
    return lines

def table6_summary(table: pd.DataFrame, run_frames: Sequence[pd.DataFrame] = ()) -> str:
    """Table 6 in plain words (Markdown): per screen scale, sharing level and noise level, the share of its start's
    error that SDM and the best peer remove and their CPU time ratio, beside the exact-match set's extent; the bars
    per screen, with where the car level's mean comes from when ``run_frames`` (the per-unit records) are given
    (:func:`tail_words`). The scaling's words are :func:`sdm.experiments.report.scaling.scaling_words`."""
    lines = ["## Table 6 in words", ""]
    for scale in _scales(table):
        lines += [f"### {screen_words(scale).capitalize()}", ""]
        for sharing in SHARING_ORDER[1:]:
            rows = _of_scale(table, scale, sharing)
            if not len(rows):
                continue
            hidden = int(rows["hidden"].max())
            compared = against_start(table, sharing, scale)
            extent = compared[0]["extent"] if compared else (math.nan, math.nan)
            where = (f"; its pixels identify it to a median {1e3 * extent[0]:.1f} x {1e3 * extent[1]:.1f}e-3 m "
                     "(the exact-match set's extent, a x b)" if not math.isnan(extent[0]) else "")
            lines.append(f"- **{UNIT[sharing].capitalize()}** ({hidden} hidden cars over the runs, left out{where}): "
                         + "; ".join(_removed_words(row) for row in compared) + ".")
            gated = against_start(table, sharing, scale, gated=True)
            if gated:
                lines.append("  With the prior gate on every method: " + "; ".join(_removed_words(row) for row in gated)
                             + ".")
        lines += [""] + _bars(table, scale) + [line for gated in (False, True)
                                               for line in tail_words(run_frames, scale, gated=gated)] + [""]
    return "\n".join(lines).rstrip("\n") + "\n"


def _bars(table: pd.DataFrame, scale: int) -> list[str]:
    """The bars of one screen: the car level's schedule noise-free and at level 2 (as it is and with the prior gate),
    every method closer than its start noise-free, the floor, SDM against the best peer at the car level (as they
    are and every method with the prior gate)."""
    own = table[table["scale"] == scale] if "scale" in table.columns else table
    lines = []
    car = own[own["sharing"] == "car"].set_index(["noise_level", "method"])
    for (noise_level, bar), gated in itertools.product(((0, 0.2), (2, 0.5)), (False, True)):
        if (noise_level, "sdm_schedule") not in car.index:
            continue
        row = car.loc[(noise_level, "sdm_schedule")]
        start = car.loc[(noise_level, "start")] if (noise_level, "start") in car.index else None
        mean, median, of_start, closer = (row[f"{'gated_' if gated else ''}{key}"]
                                          for key in ("m" if gated else "mean_m", "median_m", "of_start", "closer"))
        if math.isnan(of_start):
            continue
        moon = f"; moonshot at most 0.1x: {bar_word(of_start <= 0.1)}" if noise_level == 0 else ""
        start_median = f" against the shared start's {1e3 * start['median_m']:.1f}e-3 m" if start is not None else ""
        name = "the recommended schedule" + (" with the prior gate" if gated else "")
        lines.append(f"- Car level, noise {noise_level}: {name} ends at {of_start:.2f}x its start's mean distance "
                     f"({1e3 * mean:.1f} against {1e3 * row['start_m']:.1f}e-3 m); at most {bar}x: "
                     f"{bar_word(of_start <= bar)}{moon}. Its median is {1e3 * median:.1f}e-3 m{start_median}; "
                     f"{100 * (1 - closer):.0f} % of the cars end no closer than their start.")
    floors = own[(own["method"] == "floor") & (own["noise_level"] == 0)]
    if len(floors):
        worst = floors.loc[floors["of_start"].idxmax()]
        lines.append(f"- The floor without noise: at most {worst['of_start']:.3f}x the start's error over the "
                     f"sharing levels (worst: {worst['sharing']}); at most 0.05x: "
                     f"{bar_word(worst['of_start'] <= 0.05)}.")
    noise_free = own[(own["noise_level"] == 0) & own["method"].isin(METHODS)]
    if len(noise_free):
        worse = noise_free[noise_free["of_start"] > 1]
        lines.append("- Without noise, every method ends closer than its start on average." if not len(worse) else
                     "- Without noise, these end farther than their start on average: " + "; ".join(
                         f"{LABELS[r['method']]} ({r['sharing']}, {r['of_start']:.2f}x)" for _, r in worse.iterrows())
                     + ".")
    for gated in (False, True):
        for row in against_start(table, "car", scale, gated):
            if row["peer"] is None:
                continue
            which = "with the prior gate on every method, " if gated else ""
            if row["peer_removed"] < 0:
                lines.append(f"- Car level, noise {row['noise_level']}, {which}the best peer ({LABELS[row['peer']]}) ends "
                             "farther than its start: no ratio to it is a comparison.")
                continue
            within, cheap = row["ratio"] <= 1.5, row["speed"] >= 10
            lines.append(f"- Car level, noise {row['noise_level']}, {which}SDM's mean is {row['ratio']:.2f}x the best "
                         f"peer's ({LABELS[row['peer']]}) at 1/{row['speed']:.0f} of its CPU time; within 1.5x at no "
                         f"more than 1/10 of its time: {bar_word(within and cheap)}.")
    return lines

def plot_table6(table: pd.DataFrame, path: str | Path) -> Path:
    """Mean distance per unit against the noise level, one panel per (screen scale, sharing level), one line per
    method; the do-nothing references and the exact-match set dotted."""
    from .figures import plt, save_figure

    table = table if "scale" in table.columns else table.assign(scale=1)
    panels = [(scale, sharing) for scale in _scales(table) for sharing in SHARING_ORDER
              if len(_of_scale(table, scale, sharing))]
    fig, axes = plt.subplots(1, len(panels), figsize=(4 * len(panels), 3.6), sharey=False, squeeze=False)
    for ax, (scale, sharing) in zip(axes[0], panels):
        rows = _of_scale(table, scale, sharing)
        for index, method in enumerate(ROWS):
            own = rows[rows["method"] == method].sort_values("noise_level")
            if len(own):
                reference = method in REFERENCES or method == EXACT_SET
                ax.plot(own["noise_level"], 1e3 * own["mean_m"], marker="." if reference else "o",
                        linestyle=":" if reference else "-",
                        color={"prior": "grey", "start": "black"}.get(method, f"C{index % 10}"),
                        label=LABELS[method])
        ax.set_title(f"scale {scale}: {UNIT[sharing]}", fontsize=9)
        ax.set_xlabel("noise level (pixels)")
        ax.set_yscale("log")
    axes[0][0].set_ylabel("mean distance per unit (1e-3 m)")
    handles = {}
    for ax in axes[0]:  # one legend for every panel: a method keeps its colour everywhere
        for handle, label in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(label, handle)
    fig.legend(list(handles.values()), list(handles), fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5))
    fig.tight_layout()
    return save_figure(fig, path)

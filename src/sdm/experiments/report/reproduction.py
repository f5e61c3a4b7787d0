"""The reproduction report (``results/report/reproduction.md``): every number beside the paper's.

Everything in the report is computed from the measured tables and statistics
handed in; only the paper's values (:mod:`sdm.experiments.paper`) and the
acceptance criteria are constants. Each gap comes with the measured figures
that explain it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import pandas as pd

from .. import paper
from .tables import TABLE1_FORMAT, TABLE2_FORMAT, to_markdown

# -- acceptance criteria: the reproduction's targets --------------------------------------------
#: The noise-free mean distance must be at most this (1e-3 m).
NOISE_FREE_MAX = 1.0
#: Each noisy level's mean must lie within these factors of the paper's.
NOISY_RATIO = (0.5, 2.0)


#: Mean distances (1e-3 m) at noise levels 1 to 4 of an independent implementation on the 57 real
#: ApolloCar3D frames of ``data/apollocar3d-sample`` (docs/method/paper.md, Real layouts and the synthetic default): context, not a target.
REAL_SAMPLE_NOISY_MM = (28.0, 36.0)


@dataclass
class Check:
    """One acceptance criterion: what, the measured value, the target, pass or fail."""

    name: str
    measured: str
    target: str
    passed: bool

    def row(self) -> str:
        return f"| {self.name} | {self.measured} | {self.target} | {'PASS' if self.passed else 'FAIL'} |"


def checks(table1: pd.DataFrame, table2: pd.DataFrame) -> list[Check]:
    """The acceptance criteria on the measured tables (Table 2 in 1e-3 m)."""
    result = []
    by_level = table2.set_index("noise_level")
    if 0 in by_level.index:
        mean0 = float(by_level.loc[0, "mean"])
        result.append(Check("Table 2, level 0: mean distance", f"{mean0:.3f}e-3 m",
                            f"<= {NOISE_FREE_MAX:g}e-3 m (paper {paper.TABLE2[0]['mean']:.3f})",
                            mean0 <= NOISE_FREE_MAX))
    low, high = NOISY_RATIO
    for noise_level, row in by_level.iterrows():
        if noise_level == 0 or int(noise_level) not in paper.TABLE2:
            continue
        ratio = float(row["mean_ratio"])
        result.append(Check(f"Table 2, level {noise_level}: mean / paper's", f"{row['mean']:.3f}e-3 m = {ratio:.2f}x",
                            f"{low:g}x to {high:g}x of {row['paper_mean']:.3f}e-3 m", low <= ratio <= high))
    best = table1[table1["best"]].iloc[0]
    best_n, best_lr = paper.TABLE1_BEST
    same = int(best["n_epoch"]) == best_n and math.isclose(float(best["lr"]), best_lr)
    result.append(Check("Table 1: best cell", f"n_epoch {int(best['n_epoch'])}, lr {best['lr']:.0e}",
                        f"paper: n_epoch {best_n}, lr {best_lr:.0e}", same))
    return result


def build_report(
    table1: pd.DataFrame,
    table2: pd.DataFrame,
    distances: pd.DataFrame,
    sky_stats: Mapping[str, float],
    data_summary: Mapping[str, float],
    config: Mapping,
    timings: pd.DataFrame | None = None,
    flow_at_truth: pd.DataFrame | None = None,
) -> str:
    """The Markdown text of the reproduction report.

    Args:
        table1: :func:`sdm.experiments.report.tables.table1_frame`.
        table2: :func:`sdm.experiments.report.tables.table2_frame`.
        distances: one row per noise run (``noise_level, run, a, b, distance``; metres).
        sky_stats: statistics of the Sky dataset (``target_mean_depth``, ``configurations``, ...).
        data_summary: statistics of the annotations (``images``, ``cars_per_image``, ...).
        config: the workflow's configuration.
        timings: optional ``stage, seconds`` wall times.
        flow_at_truth: optional :func:`sdm.experiments.flow_at_true_shift` frame.
    """
    a_star, b_star = (float(v) for v in config["sky"]["shift"])
    results = checks(table1, table2)
    n_pass = sum(c.passed for c in results)
    lines = [
        "# Reproduction report",
        "",
        "Paper: *A Solution for a Fundamental Problem of 3D Inference based on 2D Representations* "
        "(Spatial Domain Mapping). Every number below is measured by this run of the workflow and "
        "set beside the paper's; the criteria: Table 2's noise-free mean at most 1e-3 m, each noisy mean within "
        "0.5x to 2x of the paper's, Table 1's best cell the paper's.",
        "",
        f"**{n_pass} of {len(results)} criteria pass.**",
        "",
        "| criterion | measured | target | result |",
        "|---|---|---|---|",
        *[c.row() for c in results],
        "",
    ]
    lines += _setup_section(config, data_summary, sky_stats)
    lines += _table1_section(table1)
    lines += _table2_section(table2, distances, sky_stats, (a_star, b_star))
    lines += _gaps_section(results, table1, table2, distances, sky_stats, data_summary, config, (a_star, b_star))
    if flow_at_truth is not None and len(flow_at_truth):
        lines += _flow_section(flow_at_truth)
    if timings is not None and len(timings):
        lines += ["## Wall time per stage", "", "| stage | seconds |", "|---|---:|"]
        lines += [f"| {row.stage} | {row.seconds:.1f} |" for row in timings.itertuples()]
        lines += [f"| total (sum over jobs) | {timings['seconds'].sum():.1f} |", ""]
    return "\n".join(lines) + "\n"


def _setup_section(config, data_summary, sky_stats) -> list[str]:
    source = config["data"]["source"]
    where = {
        "synthetic": "a synthetic annotation set in ApolloCar3D's layout (ApolloCar3D itself cannot be downloaded here)",
        "apollo": f"the ApolloCar3D folder `{config['data'].get('apollo_folder')}`",
        "pku": f"the PKU/Baidu car-pose csv `{config['data'].get('pku_csv')}`",
    }[source]
    rows = [
        ("annotated images", _fmt(data_summary.get("images"), "d"), f"{paper.N_IMAGES_APOLLO:,} (ApolloCar3D)"),
        ("cars per image", _fmt(data_summary.get("cars_per_image"), ".2f"), f"about {paper.PAPER_CARS_PER_IMAGE} (over 60K cars)"),
        ("Sky configurations", _fmt(sky_stats.get("configurations"), "d"), f"{paper.N_SKY:,}"),
        ("selected / train / dev", f"{config['split']['n_selected']} / {config['split']['n_train']} / {config['split']['n_dev']}",
         f"{paper.N_SELECTED} / {paper.N_TRAIN} / {paper.N_DEV}"),
        ("mean target depth z_bar (m)", _fmt(sky_stats.get("target_mean_depth"), ".2f"),
         f"{paper.PAPER_TARGET_DEPTH} (implied by Table 2's Avg. Dist.)"),
        ("runs per noise level", str(config["noise"]["runs"]), str(paper.RUNS_PER_LEVEL)),
        ("s, batch size", f"{config['train']['s']}, {config['train']['batch_size']}", "4, 16"),
    ]
    lines = [
        "## Setup",
        "",
        f"Data: {where}.",
        "",
        "| quantity | ours | paper |",
        "|---|---:|---:|",
        *[f"| {name} | {ours} | {theirs} |" for name, ours, theirs in rows],
        "",
    ]
    return lines


def _table1_section(table1: pd.DataFrame) -> list[str]:
    lines = ["## Table 1: hyper-parameter tuning", "", to_markdown(table1, TABLE1_FORMAT)]
    compared = table1.dropna(subset=["paper_dev_loss"])
    if len(compared):
        ratio = compared["dev_loss"] / compared["paper_dev_loss"]
        lines += [
            f"Our dev loss is {ratio.min():.2f}x to {ratio.max():.2f}x the paper's over the "
            f"{len(compared)} cells it reports.",
            "",
        ]
    return lines


def _table2_section(table2, distances, sky_stats, theta_star) -> list[str]:
    lines = ["## Table 2: accuracy and robustness", "", to_markdown(table2, TABLE2_FORMAT)]
    lines += ["Ratios ours / paper:", "", "| level | mean | std | Q1 | Q2 | Q3 | Avg. Dist. |", "|---:|---:|---:|---:|---:|---:|---:|"]
    for row in table2.itertuples():
        cells = [_ratio(getattr(row, s), getattr(row, f"paper_{s}")) for s in ("mean", "std", "q1", "q2", "q3")]
        avg = _ratio(row.avg_dist_mm, row.paper_avg_dist_mm) if row.noise_level else "-"
        lines.append(f"| {row.noise_level} | " + " | ".join(cells) + f" | {avg} |")
    lines += ["", "Where the error lies (mean of a~ - a* and b~ - b* over the runs, 1e-3 m):", "",
              "| level | mean a~ - a* | mean b~ - b* | bias length / mean distance |", "|---:|---:|---:|---:|"]
    for noise_level, bias_a, bias_b, share in _biases(distances, theta_star):
        lines.append(f"| {noise_level} | {bias_a:+.3f} | {bias_b:+.3f} | {share:.2f} |")
    lines.append("")
    return lines


def _flow_section(flow: pd.DataFrame) -> list[str]:
    """Where the noisy bias comes from: the flow at theta* itself, per noise level and zoom."""
    zooms = sorted(flow["zoom"].unique(), reverse=True)
    lines = [
        "## Why the noisy runs are biased: the flow at theta*",
        "",
        "The summed dynamic gradient flow per training configuration, evaluated *at* theta* on each noise "
        "level's training targets (run 0's draw), at every zoom level; `unmatched` is the share of points "
        "entering that level that land on the grid in a block the target leaves empty (these are the pulled ones). A gradient of zero means theta* "
        "is a fixed point of SGD; a negative value pushes theta~ *up* (SGD subtracts the gradient).",
        "",
        "| noise level | " + " | ".join(f"zoom {z}: (a, b) flow, unmatched" for z in zooms) + " |",
        "|---:|" + "---|" * len(zooms),
    ]
    for noise_level, group in flow.groupby("noise_level", sort=True):
        cells = []
        for zoom in zooms:
            row = group[group["zoom"] == zoom].iloc[0]
            cells.append(f"({row['flow_a']:+.2f}, {row['flow_b']:+.2f}), {100 * row['unmatched']:.1f}%")
        lines.append(f"| {noise_level} | " + " | ".join(cells) + " |")
    finest = flow[flow["zoom"] == min(zooms)]
    noisy = finest[finest["noise_level"] > 0]
    noise_free = finest[finest["noise_level"] == 0]
    if len(noisy):
        lines += [
            "",
            f"Without noise the flow at theta* is {'zero' if len(noise_free) and not noise_free[['flow_a', 'flow_b']].abs().to_numpy().any() else 'not zero'} "
            f"at zoom {min(zooms)}. With noise it is ({noisy['flow_a'].min():+.1f} to {noisy['flow_a'].max():+.1f}, "
            f"{noisy['flow_b'].min():+.1f} to {noisy['flow_b'].max():+.1f}) per configuration at zoom {min(zooms)}, "
            f"where {100 * noisy['unmatched'].min():.0f}% to {100 * noisy['unmatched'].max():.0f}% of the points are "
            "unmatched even at the true shift: theta* is no longer where the pulls balance, and the runs settle "
            "where they do, on the side the sign of this flow points to.",
        ]
    return lines + [""]


def _biases(distances: pd.DataFrame, theta_star) -> list[tuple[int, float, float, float]]:
    rows = []
    for noise_level, group in distances.groupby("noise_level", sort=True):
        bias_a = 1000 * float((group["a"] - theta_star[0]).mean())
        bias_b = 1000 * float((group["b"] - theta_star[1]).mean())
        mean = 1000 * float(group["distance"].mean())
        rows.append((int(noise_level), bias_a, bias_b, math.hypot(bias_a, bias_b) / mean if mean else math.nan))
    return rows


def _gaps_section(results: Sequence[Check], table1, table2, distances, sky_stats, data_summary, config,
                  theta_star) -> list[str]:
    """The report's "Gaps and their reasons": one bullet for each number outside its criterion, with its reason."""
    lines = ["## Gaps and their reasons", ""]
    biases = {noise_level: (a, b, share) for noise_level, a, b, share in _biases(distances, theta_star)}
    by_level = table2.set_index("noise_level")
    failed = {c.name for c in results if not c.passed}
    best = table1[table1["best"]].iloc[0]
    lines += _depth_gap(sky_stats)
    lines += _noise_free_gap(failed, by_level, biases)
    lines += _noisy_gaps(failed, by_level, biases, best, data_summary, sky_stats)
    lines += _table1_pick_gap(failed, table1, best)
    lines += _table1_values_gap(table1)
    if len(lines) == 2:
        lines.append("- None: every number is within the criteria.")
    lines += [
        "",
        "Not tuned to the tables: the data, the method and every setting come from the paper, and where it leaves "
        "a choice open from docs/method/paper.md; nothing here was adjusted after seeing these numbers.",
        "",
    ]
    return lines


def _depth_gap(sky_stats) -> list[str]:
    """Avg. Dist. scales with the mean target depth: ours against the paper's."""
    lines = []
    depth = sky_stats.get("target_mean_depth")
    if depth is not None and not math.isnan(float(depth)):
        lines.append(
            f"- **Avg. Dist.** is the displacement that n pixels stand for at the mean target depth, so it "
            f"scales with z_bar: ours is {float(depth):.2f} m against the {paper.PAPER_TARGET_DEPTH} m that the "
            f"paper's column implies ({float(depth) / paper.PAPER_TARGET_DEPTH:.3f}x), which is the ratio of "
            "the two columns at every level. It is a property of the data, not of the method."
        )
    return lines


def _noise_free_gap(failed, by_level, biases) -> list[str]:
    """The noise-free mean against its bar, or against the paper's where it ends closer."""
    lines = []
    if "Table 2, level 0: mean distance" in failed:
        a, b, share = biases.get(0, (math.nan, math.nan, math.nan))
        lines.append(
            f"- **Noise-free mean misses**: {by_level.loc[0, 'mean']:.3f}e-3 m against at most "
            f"{NOISE_FREE_MAX:g}e-3 m. The runs end on average ({a:+.3f}, {b:+.3f})e-3 m from theta* "
            f"(bias share {share:.2f}); "
            + ("the error is mostly a systematic offset, not run-to-run spread." if share > 0.5 else
               "the error is mostly run-to-run spread (the mini-batch order), not an offset.")
        )
    elif 0 in by_level.index and by_level.loc[0, "mean_ratio"] < NOISY_RATIO[0]:
        row = by_level.loc[0]
        lines.append(
            f"- **Noise-free runs end closer to theta* than the paper's**: mean {row['mean']:.3f}e-3 m "
            f"({row['mean_ratio']:.2f}x the paper's {row['paper_mean']:.3f}e-3 m), std {row['std']:.3f} against "
            f"{row['paper_std']:.3f}. Without noise every point can be matched exactly at theta*, so how close a "
            "run gets is set by the last level's steps; the paper gives no detail of its runs that would explain "
            "its larger spread, so this gap is reported, not explained."
        )
    return lines


def _noisy_gaps(failed, by_level, biases, best, data_summary, sky_stats) -> list[str]:
    """The noisy levels outside 0.5x-2x of the paper's mean (or all on one side of it), with the bias's reason."""
    lines = []
    noisy = [int(name.split("level ")[1].split(":")[0]) for name in sorted(failed) if name.startswith("Table 2, level")
             and not name.startswith("Table 2, level 0")]
    all_noisy = [int(noise_level) for noise_level in by_level.index if noise_level != 0 and int(noise_level) in paper.TABLE2]
    ratios = [float(by_level.loc[noise_level, "mean_ratio"]) for noise_level in all_noisy]
    one_sided = bool(ratios) and (min(ratios) > 1.25 or max(ratios) < 0.8)
    if not noisy and one_sided:
        noisy = all_noisy
        side = "above" if min(ratios) > 1 else "below"
        lines.append(
            f"- **Noisy levels are within the criteria but all {side} the paper's mean** "
            f"({min(ratios):.2f}x to {max(ratios):.2f}x):"
        )
    elif noisy:
        lines.append("- **Noisy levels outside 0.5x-2x of the paper's mean**:")
    if noisy:
        for noise_level in noisy:
            row = by_level.loc[noise_level]
            a, b, share = biases.get(noise_level, (math.nan, math.nan, math.nan))
            lines.append(
                f"  - level {noise_level}: {row['mean']:.3f}e-3 m = {row['mean_ratio']:.2f}x the paper's "
                f"{row['paper_mean']:.3f}e-3 m (std {row['std']:.3f} against {row['paper_std']:.3f}); the runs end on "
                f"average ({a:+.3f}, {b:+.3f})e-3 m from theta*, a bias that makes up {share:.2f} of the mean distance."
            )
        directions = {(bool(biases[noise_level][0] > 0), bool(biases[noise_level][1] > 0)) for noise_level in noisy}
        signs = ", ".join(f"a~ {'above' if a else 'below'} a* and b~ {'above' if b else 'below'} b*" for a, b in directions)
        lines.append(
            f"  Reason: the noisy estimates are pulled to one side ({signs}), not scattered around theta*, so the "
            "gap is the size of that pull" + (f" (our std is {_range(by_level, noisy, 'std')} the paper's)" if noisy else "")
            + ". Noise spreads each target pixel up to n pixels; a point whose landing "
            "pixel misses gets pulled by every target pixel in its 3x3 window (dynamic gradient flow, paper "
            "section 4), and where circles of different depths overlap those pulls do not cancel. How large the "
            "net pull is depends on how crowded the configurations are and on their depth mix (docs/method/paper.md, "
            "Real layouts and the synthetic default): " + _data_contrast(data_summary, sky_stats) + " These are statistics of our data; "
            "ApolloCar3D's own overlap statistics are not published, so the data cannot be checked on this point. "
            f"For scale, an independent implementation run on 57 real ApolloCar3D frames (docs/method/paper.md, Real layouts and the synthetic default) "
            f"found {REAL_SAMPLE_NOISY_MM[0]:g}e-3 to {REAL_SAMPLE_NOISY_MM[1]:g}e-3 m at levels 1 to 4, also "
            "mostly as a bias. The noise runs use our Table 1 pick"
            f" (n_epoch {int(best['n_epoch'])}, lr {best['lr']:.0e})"
            + ("" if "Table 1: best cell" not in failed else
               f", not the paper's (n_epoch {paper.TABLE1_BEST[0]}, lr {paper.TABLE1_BEST[1]:.0e}); "
               "the learning rate sets how far each noisy pull moves theta~ in the last levels")
            + "."
        )
    return lines


def _table1_pick_gap(failed, table1, best) -> list[str]:
    """Table 1's best cell where it is not the paper's."""
    lines = []
    if "Table 1: best cell" in failed:
        pick = table1[table1["paper_best"]]
        if len(pick):
            theirs = pick.iloc[0]
            tied = int(table1["tied"].sum()) if "tied" in table1 else 1
            lines.append(
                f"- **Table 1 picks another cell**: ours is n_epoch {int(best['n_epoch'])}, lr {best['lr']:.0e} "
                f"(dev loss {best['dev_loss']:.3f}"
                + (f", tied with {tied - 1} other cell(s), the lowest train loss among them"
                   f" ({best['train_loss']:.3f}; then the most epochs, the smaller lr)" if tied > 1 else "")
                + f"); at the paper's pick ours is {theirs['dev_loss']:.3f}"
                + (f", its run ending {theirs['distance_mm']:.3f}e-3 m from theta*" if "distance_mm" in table1 else "")
                + ". The dev loss counts the false-positive pixels of the zoom-0 output, which at theta* are none "
                "(docs/method/paper.md, Forward pass), so it ranks the cells by how close their single run ends to theta*"
                + (f": {best['distance_mm']:.3f}e-3 m for ours, {theirs['distance_mm']:.3f}e-3 m at the paper's pick"
                   if "distance_mm" in table1 else "")
                + ". With one run per cell, that order also reflects the run's mini-batch order, so nearby cells can "
                "swap places; the paper's order came from its data and its runs."
            )
    return lines


def _table1_values_gap(table1) -> list[str]:
    """Table 1's cells more than 2x from the paper's dev loss."""
    lines = []
    compared = table1.dropna(subset=["paper_dev_loss"])
    outside = compared[(compared["dev_loss"] < 0.5 * compared["paper_dev_loss"])
                       | (compared["dev_loss"] > 2 * compared["paper_dev_loss"])]
    if len(outside):
        lower = bool((outside["dev_loss"] < outside["paper_dev_loss"]).all())
        cells = "; ".join(
            f"n_epoch {int(r.n_epoch)}, lr {r.lr:.0e}: {r.dev_loss:.3f} vs {r.paper_dev_loss:.3f}"
            + (f" (run ends {r.distance_mm:.3f}e-3 m from theta*)" if "distance_mm" in table1 else "")
            for r in outside.itertuples()
        )
        lines.append(
            f"- **Table 1 values** differ by more than 2x in {len(outside)} of {len(compared)} cells ({cells}). "
            + "At theta* the zoom chain only loses target pixels, it never adds one (docs/method/paper.md, Forward pass), so "
            "the dev loss measures how far a cell's run ends from theta* (compare the distance column): "
            + ("ours are all lower, so our runs end closer to theta* than the paper's did. " if lower else
               "where ours is lower our run ended closer to theta* than the paper's, where higher further. ")
            + "Each cell is a single run, so its place also depends on that run's mini-batch order. The paper "
            "does not say how its dev loss was averaged (per configuration, as here, or otherwise), which can "
            "also scale it."
        )
    return lines


def _range(by_level: pd.DataFrame, noise_levels: Sequence[int], stat: str) -> str:
    ratios = [float(by_level.loc[noise_level, stat]) / float(by_level.loc[noise_level, f"paper_{stat}"]) for noise_level in noise_levels]
    return f"{min(ratios):.2f}x" if len(ratios) == 1 else f"{min(ratios):.2f}x to {max(ratios):.2f}x"


def _data_contrast(data_summary, sky_stats) -> str:
    cars = data_summary.get("cars_per_image")
    depth = sky_stats.get("target_mean_depth")
    parts = []
    if cars is not None:
        parts.append(f"{float(cars):.2f} cars per image (ApolloCar3D: about {paper.PAPER_CARS_PER_IMAGE})")
    if depth is not None:
        parts.append(f"a mean target depth of {float(depth):.2f} m (paper: {paper.PAPER_TARGET_DEPTH} m)")
    overlap = sky_stats.get("circle_overlap_rate")
    if overlap is not None:
        parts.append(f"{100 * float(overlap):.1f}% of circles overlapping another")
    return ("our data has " + ", ".join(parts) + ".") if parts else ""


def _fmt(value, spec: str) -> str:
    if value is None:
        return "-"
    try:
        if spec == "d":
            return f"{int(value):,}"
        return format(float(value), spec)
    except (TypeError, ValueError):
        return str(value)


def _ratio(ours, theirs) -> str:
    try:
        ours, theirs = float(ours), float(theirs)
    except (TypeError, ValueError):
        return "-"
    if math.isnan(ours) or math.isnan(theirs) or theirs == 0:
        return "-"
    return f"{ours / theirs:.2f}"

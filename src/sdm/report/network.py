"""Table 7 and its figure: SDM inside a network (:mod:`sdm.network`), gathered and put in words."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from ..network import LOSSES
from ..objects import REFERENCES
from ..network import SDM_RULES as SDM_RULE_NAMES
from .tables import TableFormat, write_table

#: How the table and the figure name each training loss.
LOSS_LABELS = {
    "sdm_paper": "SDM, the paper's rule",
    "sdm_recommended": "SDM, the recommended rule",
    "silhouette": "soft silhouette",
    "chamfer": "2D Chamfer",
    "supervised": "supervised, theta* labels",
}
#: Label-free losses through the SDM layer.
SDM_LOSSES = ("sdm_paper", "sdm_recommended")
#: The label-free baselines the SDM-trained network must beat.
IMAGE_LOSSES = ("silhouette", "chamfer")

TABLE7_FORMAT = TableFormat(
    columns=("level", "method", "configs", "mean", "median", "q3", "cpu_ms", "train_s"),
    headers={"level": "noise level", "method": "method", "configs": "test configs", "mean": "mean", "median": "median",
             "q3": "Q3", "cpu_ms": "CPU ms / config", "train_s": "training CPU s"},
    formats={"mean": ".2f", "median": ".2f", "q3": ".2f", "cpu_ms": ".3f", "train_s": ".1f"},
    caption="Table 7: a network trained through SDM, distance to theta* on the test set (1e-3 m) and CPU time",
    label="tab:table7",
    notes=(
        "Each test configuration has its own shift theta*_i; distances ||theta~_i - theta*_i||. The networks share "
        "architecture, data, initialisation seed and epochs; only the training loss differs.",
        "network: one forward pass; network + k: then k SDM steps per configuration from its output; CMA-ES and SDM "
        "from zero: per-configuration searches that use no network.",
        "CPU ms per configuration at test time (process time over the test set); training CPU s: the network's "
        "training, once for every level.",
        "The paper has no such table.",
    ),
)


def method_label(method: str) -> str:
    """``net:LOSS`` -> "network (LOSS)", ``net+k:LOSS`` -> "network (LOSS) + k SDM steps", the searches by name."""
    if method.startswith("net:"):
        return f"network ({LOSS_LABELS[method[4:]]})"
    if method.startswith("net+k:"):
        return f"network ({LOSS_LABELS[method[6:]]}) + k SDM steps"
    return {"cmaes": "CMA-ES per configuration", "sdm_zero": "SDM per configuration from zero",
            "prior": "do nothing: theta*'s mean", "start": "do nothing: the shared start"}[method]


def method_order(losses: Sequence[str]) -> list[str]:
    """Table 7's methods in row order: doing nothing, each network alone, then each with k steps, the searches."""
    return (list(REFERENCES) + [f"net:{loss}" for loss in losses] + [f"net+k:{loss}" for loss in losses]
            + ["cmaes", "sdm_zero"])


def table7(test_frames: Sequence[pd.DataFrame], curves: Sequence[pd.DataFrame]) -> pd.DataFrame:
    """Table 7 from :func:`sdm.network.test_methods`' frames and the training curves.

    Returns:
        One row per (noise level, method): ``configs``, the mean, median and Q3 distance (metres), the CPU
        milliseconds per configuration, and the network's training CPU seconds (NaN for the searches).
    """
    frame = pd.concat(test_frames, ignore_index=True)
    trained = {curve["loss"].iloc[0]: float(curve["train_cpu_s"].iloc[-1]) for curve in curves if len(curve)}
    losses = [loss for loss in LOSSES if loss in trained]
    order = {name: index for index, name in enumerate(method_order(losses))}
    rows = []
    for (level, method), group in frame.groupby(["level", "method"], sort=False):
        d = group["distance"].to_numpy(dtype=float)
        loss = method.split(":", 1)[1] if ":" in method else None
        rows.append({"level": int(level), "method": method, "configs": int(d.size), "mean_m": float(d.mean()),
                     "median_m": float(np.median(d)), "q3_m": float(np.quantile(d, 0.75)),
                     "cpu_ms": 1000 * float(group["cpu_s"].mean()), "train_s": trained.get(loss, np.nan)})
    table = pd.DataFrame(rows)
    return table.sort_values(["level", "method"], key=lambda c: c.map(order) if c.name == "method" else c,
                             kind="stable").reset_index(drop=True)


def write_table7(table: pd.DataFrame, stem: str | Path) -> list[Path]:
    """``stem.{csv,md,tex,html}``: the CSV in metres; the others in 1e-3 m with readable method names."""
    shown = table.assign(method=table["method"].map(method_label), mean=1e3 * table["mean_m"],
                         median=1e3 * table["median_m"], q3=1e3 * table["q3_m"])
    return write_table(table, stem, TABLE7_FORMAT, shown)


def _at(table: pd.DataFrame, level: int, method: str) -> pd.Series | None:
    rows = table[(table["level"] == level) & (table["method"] == method)]
    return rows.iloc[0] if len(rows) else None


def table7_summary(table: pd.DataFrame, steps: int, train_epochs: int, n_train: int,
                   bias: pd.DataFrame | None = None) -> str:
    """Table 7 in plain words: the bars, met or missed with their numbers, each loss's training time, and (``bias``:
    :func:`sdm.network.flow_bias`'s rows) where each SDM rule's flow vanishes on the test set."""
    levels = sorted(set(table["level"]))
    trained = [loss for loss in LOSSES if _at(table, levels[0], f"net:{loss}") is not None]
    lines = ["## Table 7 in words", ""]
    lines.append(f"Every network trained {train_epochs} epochs on {n_train} configurations (noise levels mixed); "
                 f"k = {steps} SDM steps per configuration after the network.")
    lines.append("")
    train = table.drop_duplicates("method").set_index("method")["train_s"]
    times = [f"{LOSS_LABELS[loss]} {train[f'net:{loss}']:.1f} s" for loss in trained]
    lines.append(f"- **Training CPU time** on this machine (one thread): {', '.join(times)}.")
    for loss in (loss for loss in SDM_LOSSES if loss in trained):
        lines.append(f"- **{LOSS_LABELS[loss]}, label-free, against labels**: " + _against_supervised(table, loss, levels))
        lines.append(f"- **{LOSS_LABELS[loss]} against the image losses**: " + _against_images(table, loss, levels))
    for loss in (loss for loss in SDM_LOSSES if loss in trained):
        lines.append(f"- **{LOSS_LABELS[loss]} + k SDM steps against CMA-ES**: " + _moonshot(table, loss, levels))
    reference = _against_nothing(table, trained, levels)
    if reference:
        lines.append(reference)
    best = {level: min(((row["mean_m"], row["method"]) for _, row in table[table["level"] == level].iterrows()))
            for level in levels}
    if bias is not None and len(bias):
        lines.append(_bias_words(bias))
    lines.append("- **Closest at each level**: " + "; ".join(
        f"level {level}: {method_label(method)} ({1e3 * mean:.1f}e-3 m)" for level, (mean, method) in best.items())
        + ".")
    return "\n".join(lines) + "\n"


def _against_nothing(table: pd.DataFrame, trained: Sequence[str], levels: Sequence[int]) -> str:
    """Every network against doing nothing (theta*'s mean for every configuration), per level; empty without it."""
    parts = []
    for level in levels:
        prior = _at(table, level, "prior")
        if prior is None:
            continue
        ratios = [float(_at(table, level, f"net:{loss}")["mean_m"] / prior["mean_m"]) for loss in trained]
        if ratios:
            parts.append(f"level {level}: {1e3 * prior['mean_m']:.1f}e-3 m, the networks at "
                         f"{min(ratios):.2f}-{max(ratios):.2f}x of it")
    return ("- **Doing nothing** (theta*'s mean for every configuration): " + "; ".join(parts) + ".") if parts else ""


def _bias_words(bias: pd.DataFrame) -> str:
    """Where each rule's mean flow vanishes, per level: the offset a network trained through it settles at."""
    names = {rule: label for loss, rule in SDM_RULE_NAMES.items() for label in [LOSS_LABELS[loss]]}
    parts = []
    for rule, rows in bias.groupby("rule", sort=False):
        offsets = ", ".join(f"{1e3 * row.offset_m:.1f}" for row in rows.sort_values("level").itertuples())
        levels = ", ".join(str(level) for level in sorted(rows["level"]))
        parts.append(f"{names.get(rule, rule)}: {offsets}e-3 m at levels {levels}")
    return ("- **Where the SDM flow vanishes** (its mean over the test configurations, per point, at zoom 0: "
            "-bias / stiffness from theta*, as `rule_bias` measures it; a network trained through the rule settles "
            "about there): " + "; ".join(parts) + ".")


def _ratio(table, level, method, reference) -> tuple[float, pd.Series, pd.Series] | None:
    mine, other = _at(table, level, method), _at(table, level, reference)
    if mine is None or other is None:
        return None
    return float(mine["mean_m"] / other["mean_m"]), mine, other


def _against_supervised(table, loss, levels) -> str:
    if _at(table, levels[0], "net:supervised") is None:
        return "no supervised network in this run."
    parts, met = [], []
    for level in levels:
        ratio, _, _ = _ratio(table, level, f"net:{loss}", "net:supervised")
        parts.append(f"level {level}: {ratio:.2f}x supervised's mean")
        if level in (0, 2):
            met.append(ratio <= 2.0)
    verdict = ("within 2x of supervised regression at levels 0 and 2: " + ("met" if met and all(met) else "missed")
               if met else "levels 0 and 2 not run")
    return f"{'; '.join(parts)} ({verdict})."


def _against_images(table, loss, levels) -> str:
    parts, closer = [], []
    for level in levels:
        mine = _at(table, level, f"net:{loss}")
        others = [(name, _at(table, level, f"net:{name}")) for name in IMAGE_LOSSES]
        others = [(name, row) for name, row in others if row is not None]
        if mine is None or not others:
            continue
        beats = all(mine["mean_m"] < row["mean_m"] for _, row in others)
        closer.append(beats)
        parts.append(f"level {level}: {1e3 * mine['mean_m']:.1f} against " + ", ".join(
            f"{LOSS_LABELS[name]} {1e3 * row['mean_m']:.1f}" for name, row in others) + "e-3 m")
    if not parts:
        return "no image-loss network in this run."
    verdict = "closer than both at every level: " + ("met" if all(closer) else "missed")
    return f"{'; '.join(parts)} ({verdict})."


def _moonshot(table, loss, levels) -> str:
    parts, met = [], []
    for level in levels:
        found = _ratio(table, level, f"net+k:{loss}", "cmaes")
        if found is None:
            continue
        ratio, mine, cma = found
        speed = float(cma["cpu_ms"] / mine["cpu_ms"]) if mine["cpu_ms"] > 0 else float("inf")
        parts.append(f"level {level}: {ratio:.2f}x CMA-ES's mean at 1/{speed:.0f} of its CPU time")
        met.append(ratio <= 2.0 and speed >= 100)
    if not parts:
        return "CMA-ES not run."
    return (f"{'; '.join(parts)} (within 2x of CMA-ES's mean at every level with 100x less CPU time: "
            f"{'met' if all(met) else 'missed'}).")


def plot_curves(curves: Sequence[pd.DataFrame], path: str | Path) -> Path:
    """Dev mean distance per epoch, one curve per training loss (log scale)."""
    from .figures import plt, save_figure

    fig, ax = plt.subplots(figsize=(6.2, 4.0))
    for curve in sorted(curves, key=lambda c: LOSSES.index(c["loss"].iloc[0])):
        loss = curve["loss"].iloc[0]
        ax.plot(curve["epoch"], 1e3 * curve["dev_mean_m"], marker="o", markersize=3, label=LOSS_LABELS[loss])
    ax.set_xlabel("epoch")
    ax.set_ylabel("dev mean distance to theta* (1e-3 m)")
    ax.set_yscale("log")
    ax.set_title("Learning curves: the same network, five training losses")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)


def verdict_facts(table: pd.DataFrame) -> dict:
    """Table 7 for the verdict, as data (``results/tables/table7_verdict.json``): the SDM-trained network with the lower
    mean (its loss and SDM rule), and per noise level its mean over supervised regression's and over doing nothing's
    (theta*'s mean, where the table has it), whether it is closer than every image-loss network, and the network + k
    SDM steps against CMA-ES (the ratio of means, and CMA-ES's CPU time over its own). ``loss`` None where no
    network was trained through SDM."""
    levels = sorted(int(level) for level in set(table["level"]))
    sdm = [loss for loss in SDM_LOSSES if _at(table, levels[0], f"net:{loss}") is not None]
    if not sdm:
        return {"loss": None, "levels": []}
    loss = min(sdm, key=lambda name: table.loc[table["method"] == f"net:{name}", "mean_m"].mean())
    rows = []
    for level in levels:
        mine = _at(table, level, f"net:{loss}")
        images = [_at(table, level, f"net:{name}") for name in IMAGE_LOSSES]
        refined = _ratio(table, level, f"net+k:{loss}", "cmaes")
        rows.append({
            "level": level, "mm": 1e3 * float(mine["mean_m"]),
            "to_supervised": (found[0] if (found := _ratio(table, level, f"net:{loss}", "net:supervised")) else None),
            "to_nothing": (found[0] if (found := _ratio(table, level, f"net:{loss}", "prior")) else None),
            "beats_image_losses": all(mine["mean_m"] < other["mean_m"] for other in images if other is not None),
            "refined_to_search": refined[0] if refined else None,
            "search_cpu_ratio": float(refined[2]["cpu_ms"] / refined[1]["cpu_ms"]) if refined else None,
        })
    return {"loss": loss, "rule": SDM_RULE_NAMES[loss], "label": LOSS_LABELS[loss], "levels": rows}

"""Table 7 and its figure: SDM inside a network (:mod:`sdm.experiments.network`), gathered over the training runs and put in words.

Each loss trains one network per training run; run ``r`` of every loss has the same seed (:func:`sdm.experiments.network.
training_seed`), so the runs pair across losses. A network row of Table 7 gives the mean over the runs of each
run's test-set mean distance, its spread (standard deviation, range), and the paired difference to the SDM-trained
network of the same run (:data:`PAIRED_WITH`) with its spread. The words state a ranking only where every run's
difference has the same sign (the range of the paired differences excludes 0); otherwise the two are *level*.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from ..network import LOSSES, NOTHING
from ..network import SDM_RULES as SDM_RULE_NAMES
from .tables import TableFormat, write_table

#: How the table and the figure name each training loss.
LOSS_LABELS = {
    "sdm_paper": "SDM, the paper's rule",
    "sdm_closed_centred_r1": "SDM, closed_centred_r1",
    "silhouette": "soft silhouette",
    "chamfer": "2D Chamfer",
    "supervised": "supervised, theta* labels",
}
#: Label-free losses through the SDM layer.
SDM_LOSSES = ("sdm_paper", "sdm_closed_centred_r1")
#: The label-free baselines the SDM-trained network must beat.
IMAGE_LOSSES = ("silhouette", "chamfer")
#: The SDM-trained network every other network is paired with, where it was trained (else the first SDM loss).
PAIRED_WITH = "sdm_closed_centred_r1"

TABLE7_FORMAT = TableFormat(
    columns=("noise_level", "method", "runs", "mean", "sd", "median", "offset", "diff", "diff_sd", "diff_min", "diff_max",
             "cpu_ms", "train_s", "pays_off"),
    headers={"noise_level": "noise level", "method": "method", "runs": "runs", "mean": "mean", "sd": "sd",
             "median": "median", "offset": "bias", "diff": "minus SDM: mean", "diff_sd": "sd", "diff_min": "min",
             "diff_max": "max", "cpu_ms": "CPU ms / config", "train_s": "training CPU s",
             "pays_off": "cheaper than CMA-ES from (configs)"},
    formats={"mean": ".2f", "sd": ".2f", "median": ".2f", "offset": ".2f", "diff": "+.2f", "diff_sd": ".2f",
             "diff_min": "+.2f", "diff_max": "+.2f", "cpu_ms": ".3f", "train_s": ".1f", "pays_off": ".0f"},
    caption="Table 7: networks trained through SDM and otherwise, over training runs: distance to theta* on the test "
            "set (1e-3 m), paired differences and CPU time",
    label="tab:table7",
    notes=(
        "Each test configuration has its own shift theta*_i; distances ||theta~_i - theta*_i||. The networks share "
        "architecture, data and epochs; run r of every loss starts from the same weights and draws the same "
        "shuffles and training noise, so only the training loss differs within a run.",
        "mean, sd: over the runs, of each run's mean distance on the test set; median: the runs' medians, averaged; "
        "bias: the norm of the mean error theta~ - theta* over the test set, averaged over the runs.",
        "minus SDM: each run's mean distance minus the SDM-trained network's (closed_centred_r1) of the same "
        "run, alone or with k steps as the row; mean, sd, min and max over the runs. Positive: the SDM-trained "
        "network is closer.",
        "network: one forward pass; network + k: then k SDM steps per configuration from its output; CMA-ES and SDM "
        "from zero: per-configuration searches that use no network; do nothing: one shift for every configuration.",
        "CPU ms per configuration at test time (process time over the test set); training CPU s: one network's "
        "training, the runs' mean; cheaper than CMA-ES from: the configurations from which training one network "
        "and then its CPU per configuration cost less than CMA-ES's per configuration.",
        "The paper has no such table.",
    ),
)


def method_label(method: str) -> str:
    """``net:LOSS`` -> "network (LOSS)", ``net+k:LOSS`` -> "network (LOSS) + k SDM steps", the others by name."""
    if method.startswith("net:"):
        return f"network ({LOSS_LABELS[method[4:]]})"
    if method.startswith("net+k:"):
        return f"network ({LOSS_LABELS[method[6:]]}) + k SDM steps"
    return {"cmaes": "CMA-ES per configuration", "sdm_zero": "SDM per configuration from zero",
            "prior": "do nothing: theta*'s mean", "train_mean": "do nothing: the training set's mean theta*",
            "start": "do nothing: the shared start"}[method]


def method_order(losses: Sequence[str]) -> list[str]:
    """Table 7's methods in row order: doing nothing, each network alone, then each with k steps, the searches."""
    return (list(NOTHING) + [f"net:{loss}" for loss in losses] + [f"net+k:{loss}" for loss in losses]
            + ["cmaes", "sdm_zero"])


def paired_with(losses: Sequence[str]) -> str | None:
    """The SDM loss every network is paired with: :data:`PAIRED_WITH` where trained, else the first SDM loss."""
    sdm = [loss for loss in SDM_LOSSES if loss in losses]
    return PAIRED_WITH if PAIRED_WITH in sdm else (sdm[0] if sdm else None)


def per_run(frame: pd.DataFrame) -> pd.DataFrame:
    """:func:`sdm.experiments.network.test_methods`' rows gathered per (level, method, run): ``configs``, ``mean_m``,
    ``median_m``, ``q3_m`` (distance, metres), ``offset_m`` (the norm of the mean error, metres), ``cpu_s``."""
    grouped = frame.groupby(["noise_level", "method", "run"], sort=False)
    out = grouped["distance"].agg(configs="size", mean_m="mean", median_m="median",
                                  q3_m=lambda d: float(np.quantile(d, 0.75)))
    errors = grouped[["error_a", "error_b"]].mean()
    out["offset_m"] = np.hypot(errors["error_a"], errors["error_b"])
    out["cpu_s"] = grouped["cpu_s"].mean()
    return out.reset_index()


def table7(test_frames: Sequence[pd.DataFrame], curves: Sequence[pd.DataFrame]) -> pd.DataFrame:
    """Table 7 from :func:`sdm.experiments.network.test_methods`' frames and the training curves (one per loss and run).

    Returns:
        One row per (noise level, method): ``configs``, ``runs`` (1 for a method no training run made), over the
        runs the mean, standard deviation, min and max of each run's mean distance (``mean_m``, ``sd_m``,
        ``min_m``, ``max_m``), the mean of the runs' median and Q3 and bias (``median_m``, ``q3_m``,
        ``offset_m``), the paired difference to :func:`paired_with`'s network of the same kind and run
        (``diff_m``, ``diff_sd_m``, ``diff_min_m``, ``diff_max_m``; NaN where there is none), the CPU
        milliseconds per configuration, the network's training CPU seconds (the runs' mean; NaN for the others)
        and ``pays_off``: the configurations from which training and then this method cost less than CMA-ES
        per configuration (NaN where it never does or nothing is trained). Lengths in metres.
    """
    runs = per_run(pd.concat(test_frames, ignore_index=True))
    trained = {(curve["loss"].iloc[0], int(curve["run"].iloc[0])): float(curve["train_cpu_s"].iloc[-1])
               for curve in curves if len(curve)}
    losses = [loss for loss in LOSSES if any(key[0] == loss for key in trained)]
    reference = paired_with(losses)
    rows = []
    for (noise_level, method), group in runs.groupby(["noise_level", "method"], sort=False):
        means = group.set_index("run")["mean_m"]
        loss = method.split(":", 1)[1] if ":" in method else None
        seconds = [trained[(loss, run)] for run in group["run"] if (loss, run) in trained]
        row = {"noise_level": int(noise_level), "method": method, "configs": int(group["configs"].iloc[0]),
               "runs": int(len(group)), "mean_m": float(means.mean()), "sd_m": _sd(means),
               "min_m": float(means.min()), "max_m": float(means.max()),
               "median_m": float(group["median_m"].mean()), "q3_m": float(group["q3_m"].mean()),
               "offset_m": float(group["offset_m"].mean()), **_paired(runs, noise_level, method, reference, means),
               "cpu_ms": 1000 * float(group["cpu_s"].mean()), "train_s": float(np.mean(seconds)) if seconds else np.nan}
        rows.append(row)
    table = pd.DataFrame(rows)
    table["pays_off"] = _pays_off(table)
    order = {name: index for index, name in enumerate(method_order(losses))}
    return table.sort_values(["noise_level", "method"], key=lambda c: c.map(order) if c.name == "method" else c,
                             kind="stable").reset_index(drop=True)


def _sd(values: pd.Series) -> float:
    """The sample standard deviation (NaN for fewer than two values)."""
    return float(values.std(ddof=1)) if len(values) > 1 else np.nan


def _paired(runs: pd.DataFrame, noise_level: int, method: str, reference: str | None, means: pd.Series) -> dict:
    """``method``'s run means minus the reference network's of the same kind and run: mean, sd, min, max."""
    empty = {"diff_m": np.nan, "diff_sd_m": np.nan, "diff_min_m": np.nan, "diff_max_m": np.nan}
    kind, _, loss = method.partition(":")
    if reference is None or kind not in ("net", "net+k") or loss == reference:
        return empty
    other = runs[(runs["noise_level"] == noise_level) & (runs["method"] == f"{kind}:{reference}")].set_index("run")["mean_m"]
    difference = (means - other).dropna()
    if not len(difference):
        return empty
    return {"diff_m": float(difference.mean()), "diff_sd_m": _sd(difference),
            "diff_min_m": float(difference.min()), "diff_max_m": float(difference.max())}


def _pays_off(table: pd.DataFrame) -> pd.Series:
    """Per row: the configurations ``n`` from which ``train_s + n cpu_ms`` is below ``n`` times CMA-ES's CPU per
    configuration at the row's level (NaN without training time, without CMA-ES, or where it is never so)."""
    cma = table[table["method"] == "cmaes"].set_index("noise_level")["cpu_ms"]
    saved = table["noise_level"].map(cma) - table["cpu_ms"]  # ms per configuration
    count = np.floor(1000 * table["train_s"] / saved) + 1
    return count.where((saved > 0) & table["train_s"].notna())


def write_table7(table: pd.DataFrame, stem: str | Path) -> list[Path]:
    """``stem.{csv,md,tex,html}``: the CSV in metres; the others in 1e-3 m with readable method names."""
    shown = table.assign(method=table["method"].map(method_label),
                         **{name: 1e3 * table[f"{name}_m"] for name in ("mean", "sd", "median", "offset", "diff",
                                                                          "diff_sd", "diff_min", "diff_max")})
    return write_table(table, stem, TABLE7_FORMAT, shown)


def _at(table: pd.DataFrame, noise_level: int, method: str) -> pd.Series | None:
    rows = table[(table["noise_level"] == noise_level) & (table["method"] == method)]
    return rows.iloc[0] if len(rows) else None


def trained_losses(table: pd.DataFrame) -> list[str]:
    """The losses with a network in ``table``, in :data:`sdm.experiments.network.LOSSES` order."""
    return [loss for loss in LOSSES if (table["method"] == f"net:{loss}").any()]


def ranking(row: pd.Series | None) -> str | None:
    """A paired row's ranking against the SDM-trained network: ``"closer"`` (the SDM network, at every run),
    ``"farther"`` (at every run), ``"even"`` (the runs disagree, or one run only); None without a pairing."""
    if row is None or not np.isfinite(row["diff_m"]):
        return None
    if row["runs"] > 1 and row["diff_min_m"] > 0:
        return "closer"
    if row["runs"] > 1 and row["diff_max_m"] < 0:
        return "farther"
    return "even"


def _levels_words(noise_levels: Sequence[int]) -> str:
    return ("level " if len(noise_levels) == 1 else "levels ") + ", ".join(str(noise_level) for noise_level in noise_levels)


def paired_words(table: pd.DataFrame, other: str, noise_levels: Sequence[int], kind: str = "net") -> tuple[str, dict]:
    """The SDM-trained network against ``other``'s, paired by run, in words, and each level's :func:`ranking`."""
    found = {noise_level: ranking(_at(table, noise_level, f"{kind}:{other}")) for noise_level in noise_levels}
    groups = {word: [noise_level for noise_level, found_word in found.items() if found_word == word]
              for word in ("closer", "even", "farther")}
    parts = [f"{word} at {_levels_words(found_levels)}" for word, found_levels in groups.items() if found_levels]
    return "; ".join(parts), found


def table7_summary(table: pd.DataFrame, steps: int, train: dict, n_train: int,
                   bias: pd.DataFrame | None = None) -> str:
    """Table 7 in plain words: how the networks were trained, the paired comparisons of the SDM-trained network
    (a ranking only beyond the runs' spread), the bars met or missed with their numbers, training time and where
    it pays off against CMA-ES, doing nothing, and (``bias``: :func:`sdm.experiments.network.loss_bias`' rows) where each
    label-free loss's mean gradient vanishes beside where the trained networks' mean error sits."""
    noise_levels = sorted(set(table["noise_level"]))
    trained = trained_losses(table)
    reference = paired_with(trained)
    runs = int(table.loc[table["method"].str.startswith("net:"), "runs"].max()) if trained else 0
    per_epoch = int(train.get("per_epoch", 0)) or n_train
    lines = ["## Table 7 in words", "",
             f"Every network trained {int(train['epochs'])} epochs of {min(per_epoch, n_train)} configurations "
             f"(drawn anew each epoch from {n_train}; noise levels mixed), in {runs} training runs per loss; run r "
             f"of every loss has the same seed. k = {steps} SDM steps per configuration after the network. A "
             "ranking is stated only where every run agrees (the paired differences' range excludes 0); otherwise "
             "the two are level.", ""]
    lines.append("- **Training CPU time** of one network on this machine (one thread; the runs' mean): "
                 + ", ".join(f"{LOSS_LABELS[loss]} {_at(table, noise_levels[0], f'net:{loss}')['train_s']:.1f} s"
                             for loss in trained) + ".")
    if reference is not None:
        lines += _paired_lines(table, reference, trained, noise_levels)
        lines.append(f"- **{LOSS_LABELS[reference]}, label-free, against labels**: "
                     + _against_supervised(table, reference, noise_levels))
        lines.append(f"- **{LOSS_LABELS[reference]} + k SDM steps against CMA-ES**: "
                     + _against_cmaes(table, reference, noise_levels))
    nothing = _against_nothing(table, trained, noise_levels)
    if nothing:
        lines.append(nothing)
    if bias is not None and len(bias):
        lines.append(_bias_words(bias, table, noise_levels))
    best = {noise_level: min((row["mean_m"], row["method"]) for _, row in table[table["noise_level"] == noise_level].iterrows())
            for noise_level in noise_levels}
    lines.append("- **Closest at each level** (mean over runs): " + "; ".join(
        f"level {noise_level}: {method_label(method)} ({1e3 * mean:.1f}e-3 m)" for noise_level, (mean, method) in best.items())
        + ".")
    return "\n".join(lines) + "\n"


def _paired_lines(table: pd.DataFrame, reference: str, trained: Sequence[str], noise_levels: Sequence[int]) -> list[str]:
    """One line per network paired with the reference: its difference per level with spread, and the ranking."""
    lines = []
    for other in (loss for loss in (*IMAGE_LOSSES, "supervised") if loss in trained):
        numbers = "; ".join(
            f"level {noise_level}: {1e3 * row['diff_m']:+.1f}e-3 m (sd {1e3 * row['diff_sd_m']:.1f}, "
            f"{1e3 * row['diff_min_m']:+.1f} to {1e3 * row['diff_max_m']:+.1f})"
            for noise_level in noise_levels if (row := _at(table, noise_level, f"net:{other}")) is not None)
        words, _ = paired_words(table, other, noise_levels)
        lines.append(f"- **{LOSS_LABELS[reference]} paired with {LOSS_LABELS[other]}** (the {LOSS_LABELS[other]} "
                     f"network's mean distance minus the SDM-trained network's, per run: positive, the SDM-trained one "
                     f"is closer): {numbers}. The SDM-trained network is {words}.")
    if "silhouette" in trained:
        _, found = paired_words(table, "silhouette", noise_levels)
        met = all(word == "closer" for word in found.values())
        lines.append(f"- **The SDM-trained network ahead of the silhouette-trained one beyond the runs' spread at "
                     f"every noise level**: {'met' if met else 'missed'}.")
    return lines


def _against_supervised(table: pd.DataFrame, loss: str, noise_levels: Sequence[int]) -> str:
    if _at(table, noise_levels[0], "net:supervised") is None:
        return "no supervised network in this run."
    parts, met = [], []
    for noise_level in noise_levels:
        ratio = float(_at(table, noise_level, f"net:{loss}")["mean_m"] / _at(table, noise_level, "net:supervised")["mean_m"])
        parts.append(f"level {noise_level}: {ratio:.2f}x supervised's mean")
        if noise_level in (0, 2):
            met.append(ratio <= 2.0)
    verdict = ("within 2x of supervised regression at levels 0 and 2: " + ("met" if met and all(met) else "missed")
               if met else "levels 0 and 2 not run")
    return f"{'; '.join(parts)} ({verdict})."


def _against_cmaes(table: pd.DataFrame, loss: str, noise_levels: Sequence[int]) -> str:
    parts, met = [], []
    for noise_level in noise_levels:
        mine, cma = _at(table, noise_level, f"net+k:{loss}"), _at(table, noise_level, "cmaes")
        if mine is None or cma is None:
            continue
        ratio = float(mine["mean_m"] / cma["mean_m"])
        speed = float(cma["cpu_ms"] / mine["cpu_ms"]) if mine["cpu_ms"] > 0 else math.inf
        pays = (f"cheaper than CMA-ES from {mine['pays_off']:.0f} configurations on, its training included"
                if np.isfinite(mine["pays_off"]) else "never cheaper than CMA-ES")
        parts.append(f"level {noise_level}: {ratio:.2f}x CMA-ES's mean at 1/{speed:.0f} of its CPU time per "
                     f"configuration, {pays}")
        met.append(ratio <= 2.0 and speed >= 100)
    if not parts:
        return "CMA-ES not run."
    return (f"{'; '.join(parts)} (within 2x of CMA-ES's mean at every level with 100x less CPU time: "
            f"{'met' if all(met) else 'missed'}).")


def _against_nothing(table: pd.DataFrame, trained: Sequence[str], noise_levels: Sequence[int]) -> str:
    """Every network against doing nothing (the training set's mean theta*, else theta*'s mean), per level."""
    parts = []
    for noise_level in noise_levels:
        nothing = _at(table, noise_level, "train_mean")
        nothing = nothing if nothing is not None else _at(table, noise_level, "prior")
        if nothing is None:
            continue
        ratios = [float(_at(table, noise_level, f"net:{loss}")["mean_m"] / nothing["mean_m"]) for loss in trained]
        if ratios:
            parts.append(f"level {noise_level}: {1e3 * nothing['mean_m']:.1f}e-3 m ({method_label(nothing['method'])}), "
                         f"the networks at {min(ratios):.2f}-{max(ratios):.2f}x of it")
    return ("- **Doing nothing** (one shift for every configuration): " + "; ".join(parts) + ".") if parts else ""


def _bias_words(bias: pd.DataFrame, table: pd.DataFrame, noise_levels: Sequence[int]) -> str:
    """Where each loss's mean gradient vanishes (the offset a network trained with it settles at), and the trained
    networks' own mean error, per level."""
    parts = []
    for loss, rows in bias.groupby("loss", sort=False):
        offsets = ", ".join(f"{1e3 * row.offset_m:.1f}" for row in rows.sort_values("noise_level").itertuples())
        observed = [_at(table, noise_level, f"net:{loss}") for noise_level in sorted(rows["noise_level"])]
        seen = ", ".join(f"{1e3 * row['offset_m']:.1f}" for row in observed if row is not None)
        parts.append(f"{LOSS_LABELS[loss]}: {offsets}e-3 m" + (f" (its networks' mean error: {seen}e-3 m)"
                                                               if seen else ""))
    return ("- **Where each label-free loss's gradient vanishes** (its mean over the test configurations at zoom 0: "
            f"-bias / stiffness from theta*, at {_levels_words(sorted(bias['noise_level'].unique()))}; a network trained "
            "with the loss settles about there; beside it, the norm of the trained networks' mean error): "
            + "; ".join(parts) + ".")


def plot_curves(curves: Sequence[pd.DataFrame], path: str | Path) -> Path:
    """Dev mean distance per epoch, one curve per training loss: the mean over its runs, their range shaded."""
    from .figures import plt, save_figure

    frame = pd.concat(curves, ignore_index=True)
    fig, ax = plt.subplots(figsize=(6.2, 4.0))
    for loss in (loss for loss in LOSSES if (frame["loss"] == loss).any()):
        by_epoch = 1e3 * frame[frame["loss"] == loss].groupby("epoch")["dev_mean_m"].agg(["mean", "min", "max"])
        line, = ax.plot(by_epoch.index, by_epoch["mean"], marker="o", markersize=3, label=LOSS_LABELS[loss])
        ax.fill_between(by_epoch.index, by_epoch["min"], by_epoch["max"], color=line.get_color(), alpha=0.15)
    ax.set_xlabel("epoch")
    ax.set_ylabel("dev mean distance to theta* (1e-3 m)")
    ax.set_yscale("log")
    ax.set_title("Learning curves: the same network, five training losses (runs' mean and range)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)


def verdict_facts(table: pd.DataFrame) -> dict:
    """Table 7 for the verdict, as data (``results/tables/table7_verdict.json``): the SDM-trained network every
    other is paired with (:func:`paired_with`; its loss and SDM rule), the number of training runs per loss, and per
    noise level its mean over the runs (1e-3 m), its mean over supervised regression's and over doing nothing's
    (the training set's mean theta*, else theta*'s mean), its paired ranking against each image-loss network
    (:func:`ranking`: ``closer``, ``even`` or ``farther``) and whether it is closer than all of them beyond the
    runs' spread, and the network + k SDM steps against CMA-ES (the ratio of means, CMA-ES's CPU time over its
    own, and the configurations from which its training pays off). ``loss`` None where no network was trained
    through SDM."""
    noise_levels = sorted(int(noise_level) for noise_level in set(table["noise_level"]))
    loss = paired_with(trained_losses(table))
    if loss is None:
        return {"loss": None, "levels": []}

    def ratio(noise_level: int, method: str, other: str) -> float | None:
        mine, theirs = _at(table, noise_level, method), _at(table, noise_level, other)
        return None if mine is None or theirs is None else float(mine["mean_m"] / theirs["mean_m"])

    rows = []
    for noise_level in noise_levels:
        mine = _at(table, noise_level, f"net:{loss}")
        rankings = {other: ranking(_at(table, noise_level, f"net:{other}")) for other in IMAGE_LOSSES
                    if _at(table, noise_level, f"net:{other}") is not None}
        refined, search = _at(table, noise_level, f"net+k:{loss}"), _at(table, noise_level, "cmaes")
        nothing = ratio(noise_level, f"net:{loss}", "train_mean")
        pays = float(refined["pays_off"]) if refined is not None else math.nan
        rows.append({
            "noise_level": noise_level, "mm": 1e3 * float(mine["mean_m"]),
            "to_supervised": ratio(noise_level, f"net:{loss}", "net:supervised"),
            "to_nothing": nothing if nothing is not None else ratio(noise_level, f"net:{loss}", "prior"),
            "paired": rankings,
            "beats_image_losses": bool(rankings) and all(word == "closer" for word in rankings.values()),
            "refined_to_search": ratio(noise_level, f"net+k:{loss}", "cmaes"),
            "search_cpu_ratio": (float(search["cpu_ms"] / refined["cpu_ms"])
                                 if refined is not None and search is not None else None),
            "pays_off_configs": pays if math.isfinite(pays) else None,
        })
    return {"loss": loss, "rule": SDM_RULE_NAMES[loss], "label": LOSS_LABELS[loss], "runs": int(mine["runs"]),
            "levels": rows}

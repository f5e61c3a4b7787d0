"""The scaling of Table 6 with the number of cars per image (:func:`sdm.experiments.objects.scaling_runs`): its table, its words
and its figure."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from ..objects import EXACT_SET
from .objects import LABELS, SDM_METHODS, bar_word, in_mm, screen_words


def is_gated(scaling: pd.DataFrame) -> bool:
    """Whether ``scaling`` (:func:`sdm.experiments.objects.scaling_runs`' records) scores every method after the prior gate."""
    return "gated_mean" in scaling.columns and bool(scaling["gated_mean"].notna().any())


def scaling_table(frames: Sequence[pd.DataFrame]) -> pd.DataFrame:
    """Per (scale, cars, method, budget): the mean over runs of the run's mean and median distance, its start's mean
    distance on the same cars, the share of cars ending closer than the start, CPU s per config, and the exact-match
    set's median extent per axis (its record only), and the mean distance and share closer after the prior gate. A
    frame without ``scale`` is of scale 1."""
    frame = pd.concat(frames, ignore_index=True)
    if "scale" not in frame.columns:
        frame = frame.assign(scale=1)
    columns = [c for c in ("mean", "median", "start", "closer", "cpu_s", "extent_a", "extent_b", "gated_mean",
                           "gated_closer") if c in frame.columns]
    return frame.groupby(["scale", "cars", "method", "budget"], sort=True)[columns].mean().reset_index()


def with_scaling(summary: str, scaling: pd.DataFrame | None) -> str:
    """Table 6's summary (:func:`sdm.experiments.report.objects.table6_summary`) with the scaling's words after it, if any."""
    if scaling is None or not len(scaling):
        return summary
    return (summary + "\n" + "\n".join(scaling_words(scaling))).rstrip("\n") + "\n"


def scaling_words(scaling: pd.DataFrame) -> list[str]:
    """The scaling in words: per K, doing nothing, SDM's best and the best peer's best against the start, as they are
    and every method with the prior gate (where the records score it), the exact-match extent, the bar for K >= 8
    (with the gate where scored); then the crossover against the best peer."""
    lines = []
    gated = is_gated(scaling)
    for scale, on_screen in scaling.groupby("scale", sort=False):
        lines += [f"### Scaling with the number of cars per image, {screen_words(int(scale))}", "",
                  "One shift per car, error against CPU time per configuration; x start: the mean over the mean of "
                  "the method's start on the same cars"
                  + ("; gated: every method with the prior gate, which the bar and the crossover read." if gated
                     else "."), ""]
        crossed = []
        for cars, group in on_screen.groupby("cars", sort=True):
            sdm = group[group["method"].isin(SDM_METHODS)]
            cma = group[group["method"].isin(["cmaes", "cmaes_car"])]  # the best peer: joint or per car
            if not len(sdm) or not len(cma):
                continue
            shared = group.loc[group["method"] == "start", "mean"]  # the paper's shared start, the peers' start
            start = float(shared.iloc[0]) if len(shared) else float(cma["start"].iloc[0])
            prior = group.loc[group["method"] == "prior", "mean"]
            sets = group[group["method"] == EXACT_SET]
            line = (f"- K = {cars} ({2 * cars} unknowns): doing nothing {in_mm(start)} (the shared start)"
                    + (f", {in_mm(float(prior.iloc[0]))} (theta*'s mean)" if len(prior) else "")
                    + (f"; exact-match set {1e3 * float(sets['extent_a'].iloc[0]):.1f} x "
                       f"{1e3 * float(sets['extent_b'].iloc[0]):.1f}e-3 m, any point of it "
                       f"{float(sets['mean'].iloc[0]) / start:.2f}x start" if len(sets) else ""))
            best = {}
            for column in ("mean", "gated_mean") if gated else ("mean",):
                best_sdm, best_cma = sdm.loc[sdm[column].idxmin()], cma.loc[cma[column].idxmin()]
                best[column] = best_sdm, best_cma
                line += (f"; {'gated, ' if column == 'gated_mean' else ''}SDM's best "
                         f"({LABELS[best_sdm['method']].removeprefix('SDM, ')}, {int(best_sdm['budget'])} epochs) "
                         f"{best_sdm[column] / best_sdm['start']:.2f}x its start at {1e3 * best_sdm['cpu_s']:.2f} ms, "
                         f"the best peer's ({LABELS[best_cma['method']]}, budget {int(best_cma['budget'])}) "
                         f"{best_cma[column] / best_cma['start']:.2f}x start at {1e3 * best_cma['cpu_s']:.1f} ms")
            line += " per configuration."
            column = "gated_mean" if gated else "mean"
            best_sdm, best_cma = best[column]
            crossed.append((int(cars), float(best_sdm[column]), float(best_cma[column]), start,
                            LABELS[best_cma["method"]], float(best_cma["cpu_s"] / best_sdm["cpu_s"])))
            if cars >= 8:
                if best_cma[column] > start:
                    line += " The best peer ends farther than doing nothing here: no ratio to it is a comparison."
                else:
                    within = best_sdm[column] <= 1.5 * best_cma[column]
                    cheap = best_sdm["cpu_s"] <= best_cma["cpu_s"] / 10
                    line += (f" Within 1.5x of the best peer's mean at no more than 1/10 of its time"
                             f"{' (gated)' if gated else ''}: {bar_word(within and cheap)} "
                             f"({best_sdm[column] / best_cma[column]:.2f}x its mean, "
                             f"{best_cma['cpu_s'] / best_sdm['cpu_s']:.0f}x less time).")
            lines.append(line)
        if crossed:
            lines += ["", "- " + _crossover(crossed)]
        lines.append("")
    return lines


def _crossover(crossed: list[tuple]) -> str:
    """The crossover against the best peer in plain words, from ``(K, SDM's best, peer's best, start, peer, time
    ratio)`` per K."""
    closer = [k for k, sdm, peer, *_ in crossed if sdm < peer]
    farther = [k for k, sdm, peer, *_ in crossed if sdm >= peer]
    worse = [k for k, _, peer, start, *_ in crossed if peer > start]
    ks = [k for k, *_ in crossed]
    if not closer:
        ratios = [sdm / peer for _, sdm, peer, *_ in crossed]
        words = (f"No crossover: at every K measured ({ks[0]}-{ks[-1]}) the best peer ends closer to theta* than SDM's "
                 f"best (SDM at {min(ratios):.2f}-{max(ratios):.2f}x its mean), at "
                 f"{min(r for *_, r in crossed):.0f}-{max(r for *_, r in crossed):.0f}x SDM's CPU time.")
    elif not farther:
        words = f"SDM's best ends closer to theta* than the best peer's at every K measured ({ks[0]}-{ks[-1]})."
    else:
        first = min(closer)
        behind = min(farther)
        words = (f"SDM's best ends closer to theta* than the best peer's at K = {', '.join(map(str, closer))} and "
                 f"farther at K = {', '.join(map(str, farther))}"
                 + (f": it overtakes the best peer from K = {first} on." if all(k < first for k in farther) else
                    f": the best peer overtakes it from K = {behind} on." if all(k < behind for k in closer) else "."))
    if worse:
        words += f" The best peer ends farther than doing nothing at K = {', '.join(map(str, worse))}."
    return words


def plot_scaling(scaling: pd.DataFrame, path: str | Path) -> Path:
    """Mean distance per car against CPU seconds per configuration: one curve per K and method through its budgets in
    increasing order (each with the prior gate where the records score it), doing nothing (the shared start) as a
    dotted line per K; one panel per screen scale, its legend beside it."""
    from .figures import plt, save_figure

    scaling = scaling if "scale" in scaling.columns else scaling.assign(scale=1)
    scales = list(dict.fromkeys(int(v) for v in scaling["scale"]))
    gated = is_gated(scaling)
    fig, axes = plt.subplots(1, len(scales), figsize=(9.5 * len(scales), 4.6), squeeze=False)
    for ax, scale in zip(axes[0], scales):
        own_scale = scaling[scaling["scale"] == scale]
        cars = sorted(set(own_scale["cars"]))
        colours = plt.cm.viridis(np.linspace(0, 0.9, max(len(cars), 1)))
        for colour, k in zip(colours, cars):
            for method, style, name in (("sdm_paper", "-o", "SDM, the paper's rule"),
                                        ("sdm_schedule", "-D", "SDM, the recommended schedule"),
                                        ("cmaes", "--s", "CMA-ES"),
                                        ("cmaes_car", "-.^", "CMA-ES per car")):
                own = own_scale[(own_scale["cars"] == k) & (own_scale["method"] == method)].sort_values("budget")
                if len(own):
                    ax.plot(own["cpu_s"], 1e3 * own["gated_mean" if gated else "mean"], style, color=colour,
                            markersize=4, label=f"K = {k}, {name}")
            start = own_scale[(own_scale["cars"] == k) & (own_scale["method"] == "start")]
            if len(start):
                ax.axhline(1e3 * float(start["mean"].iloc[0]), color=colour, linestyle=":", linewidth=0.8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("CPU seconds per configuration")
        ax.set_ylabel("mean distance per car (1e-3 m)")
        ax.set_title(f"Scale {scale}, one shift per car{', every method with the prior gate' if gated else ''}: SDM "
                     "(solid), CMA-ES (dashed),\ndoing nothing: the shared start (dotted)", fontsize=9)
        ax.legend(fontsize=6, ncol=1, loc="center left", bbox_to_anchor=(1.0, 0.5))
    fig.tight_layout()
    return save_figure(fig, path)

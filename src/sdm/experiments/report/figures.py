"""Figures 1-4 of the paper, theta's path per zoom level and the distance distributions.

Every function returns a :class:`matplotlib.figure.Figure` (made with pyplot);
:func:`save_figure` writes it atomically (PNG, optionally PDF) and closes it,
and :func:`show_figure` shows it inline in a notebook, saving it first when
given a path, and closes it. Screen images are drawn with rows down and columns
across, like the paper's panels.

This module leaves the matplotlib backend alone: in a Jupyter kernel (and so
under papermill) that is the inline backend, so figures render in the
notebook and in its HTML; in a plain script without a display, matplotlib
falls back to Agg by itself. (Forcing ``MPLBACKEND=Agg`` hides every plot
from the rendered notebooks.)
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import torch
from matplotlib.colors import ListedColormap
from matplotlib.patches import Rectangle

from ...camera import APOLLO_CAMERA_5, Camera
from ...errors import SDMInputError
from .. import paper
from ...mapping import explain_point
from ...sky import SKY_SHIFT, SkyConfiguration, add_target_noise, shift_vector
from .io import write_atomic

MASK_CMAP = ListedColormap(["#111111", "#f2f2f2"])
ZOOM_COLOURS = plt.get_cmap("viridis")


def _write(figure, path: Path, pdf: bool) -> None:
    write_atomic(path, lambda tmp: figure.savefig(tmp, dpi=150, bbox_inches="tight", format="png"))
    if pdf:
        write_atomic(path.with_suffix(".pdf"), lambda tmp: figure.savefig(tmp, bbox_inches="tight", format="pdf"))


def save_figure(figure, path: str | Path, pdf: bool = False) -> Path:
    """Save ``figure`` as PNG (and PDF beside it when ``pdf``), atomically, then close it."""
    path = Path(path)
    _write(figure, path, pdf)
    plt.close(figure)
    return path


def show_figure(figure, path: str | Path | None = None, pdf: bool = False) -> Path | None:
    """Show ``figure`` in the notebook (when running in one), after saving it when ``path`` is given; close it.

    Closing keeps memory flat over many figures and keeps the inline backend
    from showing the figure a second time at the end of the cell. Outside a
    Jupyter kernel nothing is shown.

    Returns:
        The PNG path written, or ``None``.
    """
    written = None
    if path is not None:
        written = Path(path)
        _write(figure, written, pdf)
    if _in_notebook():
        from IPython.display import display

        display(figure)
    plt.close(figure)
    return written


def _in_notebook() -> bool:
    """Whether this runs in a Jupyter kernel (papermill included), where ``display`` renders images."""
    try:
        from IPython import get_ipython
    except ImportError:
        return False
    shell = get_ipython()
    return shell is not None and "IPKernelApp" in getattr(shell, "config", {})


def _screen_axes(ax, image, title, cmap=MASK_CMAP, **kwargs):
    shown = ax.imshow(image, cmap=cmap, interpolation="nearest", **kwargs)
    ax.set_title(title, fontsize=10)
    ax.set_xlabel("column (screen pixels)", fontsize=8)
    ax.set_ylabel("row", fontsize=8)
    ax.tick_params(labelsize=7)
    return shown


# -- Figure 1 -------------------------------------------------------------------------------------


def figure1(configuration: SkyConfiguration, camera: Camera = APOLLO_CAMERA_5):
    """One Sky configuration: (a) binary mask of E', (b) E' as depth, (c) the target L."""
    circles = configuration.circles(camera).numpy()
    fig, axes = plt.subplots(3, 1, figsize=(7, 10.5), constrained_layout=True)
    _screen_axes(axes[0], circles > 0, f"(a) binary mask of E' ({configuration.num_points} active pixels)")
    if configuration.centres.numel():
        centres = configuration.centres.numpy()
        axes[0].scatter(centres[:, 1], centres[:, 0], s=8, c="#d62728", label="car centres (E)")
        axes[0].legend(loc="upper right", fontsize=7)
    depth = np.where(circles > 0, circles, np.nan)
    shown = _screen_axes(axes[1], depth, "(b) E' (depth of the nearest circle; brighter is bigger)", cmap="magma")
    fig.colorbar(shown, ax=axes[1], shrink=0.8, label="depth z (m)")
    target = configuration.target.numpy()
    _screen_axes(axes[2], target, f"(c) target L = E' moved by theta* ({int(target.sum())} active pixels)")
    fig.suptitle(f"Figure 1: a configuration of the Sky dataset ({configuration.image_id})", fontsize=11)
    return fig


# -- Figures 2 and 3: one point through one SDM zoom level ---------------------------------------


def pick_point(configuration: SkyConfiguration, theta: Sequence[float], camera: Camera = APOLLO_CAMERA_5,
               matched: bool | None = None, zoom: int = 0):
    """Choose a point of ``configuration`` for the single-point figures.

    Takes the point whose depth is nearest the configuration's median depth among those that
    satisfy ``matched`` (None: any) at ``theta`` and have a non-zero pull when unmatched.

    Returns:
        ``(shifted point (3,), pixel (row, col), explanation dict)``.
    """
    if configuration.num_points == 0:
        raise SDMInputError(f"configuration {configuration.image_id!r} has no point to draw")
    points = configuration.points(camera)
    points = points + shift_vector(theta, points)
    median = configuration.depth.median()
    order = torch.argsort((configuration.depth - median).abs(), stable=True)
    fallback = None
    for index in order.tolist():
        pixel = tuple(int(v) for v in configuration.pixels[index])
        info = explain_point(points[index], pixel, configuration.target, zoom=zoom, camera=camera)
        fallback = fallback or (points[index], pixel, info)
        if matched is None:
            return points[index], pixel, info
        if info["matched"] == matched and (matched or bool(info["pull"].abs().sum() > 0)):
            return points[index], pixel, info
    return fallback


def _window(ax, info, zoom: int = 0):
    """Draw the 3x3 window of blocks around the point's block, in screen coordinates."""
    size = 1 << zoom
    block = info["block"].numpy()
    for dk in (-1, 0, 1):
        for dl in (-1, 0, 1):
            top, left = (block[0] + dk) * size, (block[1] + dl) * size
            ax.add_patch(Rectangle((left, top), size, size, fill=False, lw=0.8, ec="#888888"))
    low, high = (block - 1.5) * size, (block + 2.5) * size
    ax.set_xlim(low[1], high[1])
    ax.set_ylim(high[0], low[0])
    ax.set_aspect("equal")
    ax.set_xlabel("column", fontsize=8)
    ax.set_ylabel("row", fontsize=8)
    ax.tick_params(labelsize=7)


def figure2(point: torch.Tensor, original: torch.Tensor, info: dict, zoom: int = 0,
            camera: Camera = APOLLO_CAMERA_5):
    """The forward pass on a single point (paper, Figure 2).

    Args:
        point: the shifted point ``q + (a~, b~, 0)``; ``original``: the point ``q``.
        info: :func:`sdm.mapping.explain_point` of ``point`` at the pixel of ``q``.
    """
    size = 1 << zoom
    original_screen = camera.project(original).numpy()
    shifted_screen = info["point_screen"].numpy()
    screen = info["screen"].numpy().reshape(9, 2)
    kernel = info["kernel"].numpy()
    landing = info["landing"].numpy()
    block = info["block"].numpy()
    fig, axes = plt.subplots(1, 4, figsize=(15, 4.2), constrained_layout=True)
    titles = [
        "(a) active pixel of I and its 3D point",
        "(b) I~: the point moved by theta~ (same pixel)",
        "(c) kernel D over the 9 XY-adjustments",
        "(d) output: the point at its landing pixel",
    ]
    for ax, title in zip(axes, titles):
        _window(ax, info, zoom)
        ax.set_title(title, fontsize=9)
    home = Rectangle((block[1] * size, block[0] * size), size, size, color="#ff7f0e", alpha=0.7)
    axes[0].add_patch(home)
    axes[0].plot(original_screen[1], original_screen[0], "o", color="#ff7f0e", mec="k", ms=9, label="P(q)")
    axes[1].add_patch(Rectangle((block[1] * size, block[0] * size), size, size, color="#ff7f0e", alpha=0.7))
    axes[1].plot(shifted_screen[1], shifted_screen[0], "o", color="#2ca02c", mec="k", ms=9, label="P(q + theta~)")
    axes[1].annotate("", xy=(shifted_screen[1], shifted_screen[0]), xytext=(original_screen[1], original_screen[0]),
                     arrowprops={"arrowstyle": "->", "color": "k"})
    for k in range(3):
        for l in range(3):
            top, left = (block[0] + k - 1) * size, (block[1] + l - 1) * size
            axes[2].add_patch(Rectangle((left, top), size, size, color="#d62728", alpha=0.1 + 0.85 * kernel[k, l]))
            axes[2].text(left + size / 2, top + 0.22 * size, f"D = {kernel[k, l]:.2f}", ha="center", va="center", fontsize=7)
    axes[2].scatter(screen[:, 1], screen[:, 0], s=25, facecolors="none", edgecolors="#1f77b4", label="P(T) (XY-adjustments)")
    axes[2].plot(shifted_screen[1], shifted_screen[0], "o", color="#2ca02c", mec="k", ms=7, label="P(q + theta~)")
    axes[3].add_patch(Rectangle((landing[1] * size, landing[0] * size), size, size, color="#2ca02c", alpha=0.8))
    axes[3].plot(shifted_screen[1], shifted_screen[0], "o", color="#2ca02c", mec="k", ms=7)
    for ax in axes[:3]:
        ax.legend(loc="lower left", fontsize=7)
    fig.suptitle(f"Figure 2: SDM forward pass on one point (zoom {zoom}, depth {float(point[2]):.1f} m)", fontsize=11)
    return fig


def figure3(point: torch.Tensor, info: dict, zoom: int = 0):
    """The backward pass on a single point (paper, Figure 3): which target blocks pull it, and where to."""
    size = 1 << zoom
    shifted = info["point_screen"].numpy()
    landing = info["landing"].numpy()
    block = info["block"].numpy()
    active = info["active"].numpy()
    pull = info["pull"].numpy()
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.4), constrained_layout=True)
    for ax in axes:
        _window(ax, info, zoom)
    axes[0].set_title("(a) output L~: the point's landing pixel", fontsize=9)
    axes[0].add_patch(Rectangle((landing[1] * size, landing[0] * size), size, size, color="#2ca02c", alpha=0.8))
    axes[1].set_title("(b) L~ (green) and the target L (dashed)", fontsize=9)
    axes[1].add_patch(Rectangle((landing[1] * size, landing[0] * size), size, size, color="#2ca02c", alpha=0.5))
    axes[2].set_title("(c) pulls from unmatched target pixels", fontsize=9)
    for k in range(3):
        for l in range(3):
            if not active[k, l]:
                continue
            top, left = (block[0] + k - 1) * size, (block[1] + l - 1) * size
            for ax in axes[1:]:
                ax.add_patch(Rectangle((left + 0.05, top + 0.05), size - 0.1, size - 0.1, fill=False, ls="--", lw=1.5, ec="k"))
            if not info["matched"] and (block[0] + k - 1, block[1] + l - 1) != tuple(landing):
                centre = (left + size / 2, top + size / 2)
                axes[2].annotate("", xy=centre, xytext=(shifted[1], shifted[0]),
                                 arrowprops={"arrowstyle": "->", "color": "#1f77b4", "lw": 1.2})
    for ax in axes:
        ax.plot(shifted[1], shifted[0], "o", color="#2ca02c", mec="k", ms=7)
    # The descent direction on theta~ = -gradient; drawn in screen units (x -> columns, y -> rows).
    step = -pull
    if np.abs(step).sum() > 0:
        scale = 0.45 * size / np.abs(step).max()
        axes[2].annotate("", xy=(shifted[1] + scale * step[0], shifted[0] + scale * step[1]),
                         xytext=(shifted[1], shifted[0]),
                         arrowprops={"arrowstyle": "-|>", "color": "k", "lw": 2.5})
    status = "matched: no gradient" if info["matched"] else f"gradient on (a~, b~) = ({pull[0]:+.0f}, {pull[1]:+.0f})"
    axes[2].text(0.02, 0.02, status + "\nblack: descent step -grad", transform=axes[2].transAxes, fontsize=8,
                 va="bottom", bbox={"fc": "white", "alpha": 0.8})
    fig.suptitle(f"Figure 3: SDM backward pass on one point (zoom {zoom}, depth {float(point[2]):.1f} m)", fontsize=11)
    return fig


# -- Figure 4 -------------------------------------------------------------------------------------


def figure4(target: torch.Tensor, noise_levels: Sequence[int] = (0, 1, 2, 3, 4), seed: int = 0):
    """One target at each noise level (paper, Figure 4); the noise is drawn from ``seed``."""
    generator = torch.Generator().manual_seed(int(seed))
    fig, axes = plt.subplots(len(noise_levels), 1, figsize=(7, 3.1 * len(noise_levels)), constrained_layout=True)
    axes = np.atleast_1d(axes)
    for index, (ax, noise_level) in enumerate(zip(axes, noise_levels)):
        noisy = add_target_noise(target, int(noise_level), generator)
        label = "original target L" if noise_level == 0 else f"{noise_level}-pixel noise"
        _screen_axes(ax, noisy.numpy(), f"({chr(97 + index)}) {label} ({int(noisy.sum())} active pixels)")
    fig.suptitle("Figure 4: effect of the noise on a target", fontsize=11)
    return fig


# -- theta's path ---------------------------------------------------------------------------------


def theta_path_figure(history: pd.DataFrame, theta_star: Sequence[float] = SKY_SHIFT, title: str = ""):
    """theta~'s path during training, one colour per zoom level.

    Args:
        history: :meth:`sdm.train.History.to_frame` (columns ``step, zoom, a, b``; theta after each step).
    """
    a_star, b_star = theta_star
    zooms = sorted(history["zoom"].unique(), reverse=True)
    colours = {zoom: ZOOM_COLOURS(i / max(1, len(zooms) - 1)) for i, zoom in enumerate(zooms)}
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8), constrained_layout=True)
    previous = (0.0, 0.0)
    distance = np.hypot(history["a"] - a_star, history["b"] - b_star)
    for zoom in zooms:
        part = history[history["zoom"] == zoom]
        a = np.concatenate([[previous[0]], part["a"].to_numpy()])
        b = np.concatenate([[previous[1]], part["b"].to_numpy()])
        axes[0].plot(a, b, ".-", ms=3, lw=1, color=colours[zoom], label=f"zoom {zoom} (blocks of {2 ** zoom})")
        axes[1].semilogy(part["step"], distance[part.index], ".-", ms=2, lw=1, color=colours[zoom], label=f"zoom {zoom}")
        previous = (float(part["a"].iloc[-1]), float(part["b"].iloc[-1]))
    axes[0].plot([0], [0], "ks", label="start (0, 0)")
    axes[0].plot([a_star], [b_star], "r*", ms=14, label=f"theta* = ({a_star}, {b_star})")
    axes[0].set_xlabel("a~ (m)")
    axes[0].set_ylabel("b~ (m)")
    axes[0].set_title("path of theta~ = (a~, b~)")
    axes[0].legend(fontsize=8)
    axes[0].grid(alpha=0.3)
    axes[1].set_xlabel("SGD step")
    axes[1].set_ylabel("||theta~ - theta*|| (m)")
    axes[1].set_title(f"distance to theta* (final {distance.iloc[-1] * 1000:.3f}e-3 m)")
    axes[1].grid(alpha=0.3, which="both")
    axes[1].legend(fontsize=8)
    fig.suptitle(title or "theta~ during training, per zoom level", fontsize=11)
    return fig


# -- distances per noise level --------------------------------------------------------------------


def distances_figure(distances: pd.DataFrame):
    """Distances ||theta~ - theta*|| per noise level (1e-3 m, log scale), with the paper's mean and quartiles."""
    noise_levels = sorted(distances["noise_level"].unique())
    fig, ax = plt.subplots(figsize=(9, 5), constrained_layout=True)
    data = [1000 * distances.loc[distances["noise_level"] == noise_level, "distance"].to_numpy() for noise_level in noise_levels]
    ax.boxplot(data, positions=range(len(noise_levels)), widths=0.5, showfliers=False)
    rng = np.random.default_rng(0)
    for i, values in enumerate(data):
        ax.scatter(i - 0.12 + 0.24 * rng.random(values.size), values, s=9, alpha=0.6, color="#1f77b4",
                   label="our runs" if i == 0 else None)
    for i, noise_level in enumerate(noise_levels):
        ref = paper.TABLE2.get(int(noise_level))
        if ref is None:
            continue
        ax.errorbar(i + 0.38, ref["q2"], yerr=[[ref["q2"] - ref["q1"]], [ref["q3"] - ref["q2"]]], fmt="none",
                    ecolor="#d62728", capsize=4, label="paper Q1-Q3" if i == 0 else None)
        ax.plot(i + 0.38, ref["mean"], "x", color="#d62728", ms=8, mew=2, label="paper mean" if i == 0 else None)
        ax.plot(i, data[i].mean(), "D", color="k", ms=5, label="our mean" if i == 0 else None)
    ax.set_yscale("log")
    ax.set_xticks(range(len(noise_levels)), [f"{noise_level}-pixel" for noise_level in noise_levels])
    ax.set_xlabel("noise level")
    ax.set_ylabel("||theta~ - theta*|| (1e-3 m)")
    ax.set_title(f"Distances per noise level ({len(distances)} runs)")
    ax.grid(alpha=0.3, which="both", axis="y")
    ax.legend(fontsize=8, loc="upper left")
    return fig

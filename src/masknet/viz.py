"""Static pictures (matplotlib, headless): a pair and its predicted inliers."""

from __future__ import annotations

import os
import textwrap
from pathlib import Path

import numpy as np

from masknet._atomic import atomic_target
from masknet._extras import pyplot

__all__ = [
    "DISTANCE_COLOURS",
    "display_index",
    "display_points",
    "distance_colours",
    "fit_title",
    "plot_clouds",
    "plot_learning_curve",
    "plot_mask",
    "plot_registration",
]

# The scale of distances to the template, from 0 to the limit and beyond: viridis's
# anchors (dark blue, teal, green, yellow), readable in grey and by colour-blind readers.
DISTANCE_COLOURS = np.array(
    [
        [0.267, 0.005, 0.329],
        [0.229, 0.322, 0.546],
        [0.128, 0.567, 0.551],
        [0.369, 0.789, 0.383],
        [0.993, 0.906, 0.144],
    ]
)

GREY, BLUE = "#b0b0b0", "#1f77b4"
TP, FP, FN = "#2ca02c", "#d62728", "#ff7f0e"


def plot_mask(
    template: np.ndarray,
    source: np.ndarray,
    predicted: np.ndarray,
    path: str | os.PathLike,
    truth: np.ndarray | None = None,
    title: str | None = None,
) -> Path:
    """Write a PNG of template (N, 3), source (M, 3) and the predicted mask (N,) bool.

    Left: the inputs as given. Middle: the ground-truth inliers when ``truth`` (N,)
    is known, else the source. Right: the template coloured by the prediction, split
    into true positives, false positives and misses when the truth is known.
    """
    plt = pyplot()

    predicted = np.asarray(predicted, bool)
    fig = plt.figure(figsize=(13, 4.6), dpi=110)
    lim = np.abs(np.concatenate([template, source])).max()

    def panel(i: int, heading: str):
        ax = fig.add_subplot(1, 3, i, projection="3d")
        ax.set_title(heading, fontsize=10)
        ax.set_xlim(-lim, lim), ax.set_ylim(-lim, lim), ax.set_zlim(-lim, lim)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=20, azim=-60)
        ax.set_xlabel("x"), ax.set_ylabel("y"), ax.set_zlabel("z")
        return ax

    ax = panel(1, "input: template (grey), source (blue)")
    ax.scatter(*template.T, s=2, c=GREY, label=f"template ({len(template)})")
    ax.scatter(*source.T, s=2, c=BLUE, label=f"source ({len(source)})")
    ax.legend(loc="upper left", fontsize=7, markerscale=4)

    if truth is None:
        ax = panel(2, "source (partial)")
        ax.scatter(*source.T, s=2, c=BLUE)
    else:
        truth = np.asarray(truth, bool)
        ax = panel(2, "template: true inliers (seen by the source)")
        ax.scatter(*template[~truth].T, s=1, c=GREY, label=f"not seen ({(~truth).sum()})")
        ax.scatter(*template[truth].T, s=3, c=TP, label=f"seen ({truth.sum()})")
        ax.legend(loc="upper left", fontsize=7, markerscale=4)

    ax = panel(3, "template: predicted inliers")
    if truth is None:
        ax.scatter(*template[~predicted].T, s=1, c=GREY, label="outlier")
        ax.scatter(*template[predicted].T, s=3, c=TP, label=f"predicted inlier ({predicted.sum()})")
    else:
        groups = [
            (~predicted & ~truth, GREY, "correctly rejected", 1),
            (predicted & truth, TP, "true positive", 3),
            (predicted & ~truth, FP, "false positive", 4),
            (~predicted & truth, FN, "missed inlier", 4),
        ]
        for sel, colour, name, size in groups:
            ax.scatter(*template[sel].T, s=size, c=colour, label=f"{name} ({sel.sum()})")
    ax.legend(loc="upper left", fontsize=7, markerscale=4)
    if title:
        fit_title(fig, title, fontsize=11)
    return _save(fig, path)


def point_count_label(shown: int, total: int) -> str:
    """``"1,234"``, or ``"20,000 of 241,407 shown"`` for a subsampled layer."""
    return f"{total:,}" if shown == total else f"{shown:,} of {total:,} shown"


def display_index(points: np.ndarray, max_points: int) -> np.ndarray:
    """The rows of (P, 3) points drawn: the finite ones, evenly subsampled to at most
    ``max_points`` (indices into ``points``, so per-point colours follow them)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    rows = np.flatnonzero(np.isfinite(points).all(1))
    if len(rows) > max_points:
        rows = rows[np.linspace(0, len(rows) - 1, max_points).astype(int)]
    return rows


def display_points(points: np.ndarray, max_points: int) -> np.ndarray:
    """Finite rows of (P, 3) points, evenly subsampled to at most ``max_points`` for drawing."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return points[display_index(points, max_points)]


def distance_colours(distances: np.ndarray, limit: float) -> np.ndarray:
    """(P,) distances -> (P, 3) RGB in [0, 1] on :data:`DISTANCE_COLOURS`, from 0 to
    ``limit`` (farther points take the last colour)."""
    t = np.clip(np.asarray(distances, dtype=np.float64) / max(limit, 1e-300), 0, 1)
    position = t * (len(DISTANCE_COLOURS) - 1)
    low = np.minimum(position.astype(int), len(DISTANCE_COLOURS) - 2)
    frac = (position - low)[:, None]
    return DISTANCE_COLOURS[low] * (1 - frac) + DISTANCE_COLOURS[low + 1] * frac


def plot_clouds(
    layers: dict[str, tuple[np.ndarray, str]],
    path: str | os.PathLike,
    title: str | None = None,
    max_points: int = 20_000,
) -> Path:
    """Write a PNG of named clouds, name -> ((P, 3) points, colour), from two viewpoints.

    Clouds keep their relative pose (one shared, equal-aspect frame); layers larger
    than ``max_points`` are subsampled evenly for drawing.
    """
    plt = pyplot()

    clouds, counts = {}, {}
    for name, (points, colour) in layers.items():
        clouds[name] = (display_points(points, max_points), colour)
        counts[name] = point_count_label(
            len(clouds[name][0]), len(np.asarray(points).reshape(-1, 3))
        )
    every = np.concatenate([p for p, _ in clouds.values()])
    mid = (every.max(0) + every.min(0)) / 2
    half = max((every.max(0) - every.min(0)).max() / 2, 1e-12)
    fig = plt.figure(figsize=(11, 5), dpi=110)
    for i, (elev, azim) in enumerate(((20, -60), (70, 30))):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        for name, (points, colour) in clouds.items():
            ax.scatter(*points.T, s=2, c=colour, label=f"{name} ({counts[name]})")
        for axis, centre in zip("xyz", mid, strict=True):
            getattr(ax, f"set_{axis}lim")(centre - half, centre + half)
            getattr(ax, f"set_{axis}label")(axis)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=elev, azim=azim)
        ax.set_title(f"view {i + 1}", fontsize=10)
        if i == 0:
            ax.legend(loc="upper left", fontsize=8, markerscale=4)
    if title:
        fit_title(fig, title, fontsize=11)
    return _save(fig, path)


def plot_registration(
    template: np.ndarray,
    source: np.ndarray,
    registered: np.ndarray,
    distances: np.ndarray,
    limit: float,
    path: str | os.PathLike,
    title: str,
    verdict: str,
    max_points: int = 20_000,
) -> Path:
    """Write a before/after PNG of a registration: the template (N, 3) with the source as
    given (M, 3), then with the registered source (M, 3) coloured by ``distances`` (M,) to
    the template, 0 to ``limit`` in the clouds' units; ``verdict`` is written under it."""
    plt = pyplot()
    from matplotlib.colors import LinearSegmentedColormap, Normalize

    cmap = LinearSegmentedColormap.from_list("distance", DISTANCE_COLOURS)
    tpl = display_points(template, max_points)
    rows = display_index(registered, max_points)
    panels = [
        ("before: the source as given", display_points(source, max_points), BLUE),
        (
            "after: registered, coloured by distance",
            registered[rows],
            distance_colours(distances[rows], limit),
        ),
    ]
    every = np.concatenate([tpl, *(p for _, p, _ in panels)])
    mid, half = (
        (every.max(0) + every.min(0)) / 2,
        max((every.max(0) - every.min(0)).max() / 2, 1e-12),
    )
    fig = plt.figure(figsize=(11, 5.4), dpi=110)
    for i, (name, points, colour) in enumerate(panels):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        ax.scatter(*tpl.T, s=1, c=GREY, alpha=0.5, label=f"template ({len(template):,})")
        ax.scatter(*points.T, s=2, c=colour, label=f"source ({len(source):,})")
        for axis, centre in zip("xyz", mid, strict=True):
            getattr(ax, f"set_{axis}lim")(centre - half, centre + half)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=20, azim=-60)
        ax.set_title(name, fontsize=10)
        ax.legend(loc="upper left", fontsize=8, markerscale=4)
    bar = fig.colorbar(
        plt.cm.ScalarMappable(norm=Normalize(0, limit), cmap=cmap),
        ax=fig.axes[-1],
        shrink=0.6,
        pad=0.1,
    )
    bar.set_label("distance to the template (input units; farther: yellow)", fontsize=8)
    fit_title(fig, f"{title}\n{verdict}", fontsize=10)
    return _save(fig, path)


def fit_title(fig, text: str, fontsize: float) -> None:
    """``fig``'s title, each line wrapped at word breaks to fit the figure's width (a long
    verdict or file name would run off both edges, the title being centred)."""
    width_pt = fig.get_figwidth() * 72 * 0.96  # a margin at either edge
    columns = max(20, int(width_pt / (0.5 * fontsize)))  # a first guess: mean glyph width
    renderer = fig.canvas.get_renderer()
    while True:
        wrapped = "\n".join(textwrap.fill(line, columns) for line in text.splitlines())
        title = fig.suptitle(wrapped, fontsize=fontsize)
        # The guess is checked on the rendered text: narrow it until the title fits.
        if title.get_window_extent(renderer).width <= width_pt * fig.dpi / 72 or columns <= 20:
            return
        columns = int(columns * 0.9)


def _save(fig, path: str | os.PathLike) -> Path:
    """Write a figure atomically (temporary file, then rename) and close it."""
    plt = pyplot()
    fig.tight_layout()
    path = Path(path)
    try:
        with atomic_target(path, suffix=".png") as tmp:
            fig.savefig(tmp)
    finally:
        plt.close(fig)
    return path


def plot_learning_curve(history: list[dict], path: str | os.PathLike, metric: str) -> Path:
    """A training run's curve: loss (left) and ``metric`` (right) per epoch, training and
    validation, from the loop's log rows (``train_loss``, ``val_<metric>``, ...)."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4))
    epochs = [row["epoch"] for row in history]
    for ax, key in zip(axes, ("loss", metric), strict=True):
        for split, style in (("train", "-"), ("val", "--")):
            values = [row.get(f"{split}_{key}") for row in history]
            if any(v is not None for v in values):
                ax.plot(epochs, values, style, marker="o", markersize=3, label=split)
        ax.set_xlabel("epoch")
        ax.set_title(key)
        ax.grid(alpha=0.3)
        ax.legend()
    if history:
        hours = history[-1].get("elapsed_min", 0.0) / 60
        count = f"{len(history)} epoch{'s' if len(history) != 1 else ''}"
        fig.suptitle(f"{count}, {hours:.1f} h of training", fontsize=10)
    return _save(fig, path)

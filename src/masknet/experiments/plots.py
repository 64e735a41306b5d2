"""The experiments' pictures: lines against a swept setting, and bars per pipeline."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from masknet._extras import pyplot

__all__ = ["bar_plot", "error_bars", "line_plot", "panel_plot", "series_by"]


def line_plot(
    path: Path,
    x: list[float],
    lines: dict[str, list[float]],
    xlabel: str,
    ylabel: str,
    title: str,
    baseline: tuple[str, list[float]] | None = None,
) -> None:
    """One line per entry of ``lines`` over ``x``: one colour per method X, Mask-X solid and
    plain X dashed; ``baseline`` (label, values) dotted grey."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4 if len(lines) <= 6 else 7.6, 4.2), dpi=110)
    bases = list(dict.fromkeys(name.removeprefix("Mask-") for name in lines))
    palette = plt.get_cmap("tab10")
    for name, ys in lines.items():
        style = "-" if "Mask" in name else "--"
        colour = palette(bases.index(name.removeprefix("Mask-")) % 10)
        ax.plot(x, ys, style, marker="o", markersize=4, color=colour, label=name)
    if baseline is not None:
        ax.plot(x, baseline[1], ":", color="grey", label=baseline[0])
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small", ncol=2 if len(lines) > 6 else 1)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def panel_plot(
    path: Path,
    x: list[float],
    panels: dict[str, dict[str, list[float]]],
    xlabel: str,
    ylabel: str,
    title: str,
) -> None:
    """Small multiples: one panel per entry of ``panels`` (title -> lines over ``x``), the
    same lines in the same colours in every panel, one legend."""
    plt = pyplot()
    cols = min(len(panels), 3)
    rows = -(-len(panels) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.4 * cols, 2.8 * rows + 0.6), dpi=110)
    axes = np.atleast_1d(axes).ravel()
    palette = plt.get_cmap("tab10")
    names = list(dict.fromkeys(n for lines in panels.values() for n in lines))
    for ax, (panel, lines) in zip(axes, panels.items(), strict=False):
        for name, ys in lines.items():
            ax.plot(x[: len(ys)], ys, marker="o", markersize=4, color=palette(names.index(name)))
        ax.set_title(panel, fontsize="medium")
        ax.set_xticks(x)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    for ax in axes[len(panels) :]:
        ax.axis("off")
    handles = [plt.Line2D([], [], color=palette(i), marker="o") for i in range(len(names))]
    fig.legend(handles, names, loc="lower center", ncol=len(names), fontsize="small")
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.savefig(path)
    plt.close(fig)


def bar_plot(
    path: Path, names: list[str], series: dict[str, list[float]], ylabel: str, title: str
) -> None:
    """Grouped bars: one group per name, one bar per series."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.2), dpi=110)
    width = 0.8 / len(series)
    for i, (label, values) in enumerate(series.items()):
        ax.bar(np.arange(len(names)) + i * width, values, width, label=label)
    ax.set_xticks(np.arange(len(names)) + width * (len(series) - 1) / 2)
    ax.set_xticklabels(names, rotation=20, ha="right")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(axis="y", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def error_bars(path: Path, rows: list[dict], title: str) -> None:
    """Mean and median rotation error of each pipeline row, as bars."""
    bar_plot(
        path,
        [r["pipeline"] for r in rows],
        {"mean": [r["rot_mean"] for r in rows], "median": [r["rot_median"] for r in rows]},
        "rotation error (degrees)",
        title,
    )


def series_by(
    rows: list[dict], value: str, by: str = "pipeline", names: list[str] | None = None
) -> dict[str, list[float]]:
    """``row[value]`` of each row, grouped by ``row[by]`` (in first-seen order, or ``names``)."""
    names = list(dict.fromkeys(r[by] for r in rows)) if names is None else names
    return {n: [r[value] for r in rows if r[by] == n] for n in names}

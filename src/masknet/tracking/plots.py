"""``trajectory.png``: a tracked object's path over the frames, and its fit over time."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from masknet.geometry.se3 import transform_points
from masknet.viz import _save, display_points, fit_title, pyplot

__all__ = ["STATE_COLOURS", "plot_trajectory"]

STATE_COLOURS = {
    "found": "tab:blue",
    "tracked": "tab:green",
    "refound": "tab:orange",
    "lost": "red",
}


def plot_trajectory(
    template: np.ndarray,
    frame: np.ndarray,
    transforms: np.ndarray,
    fitness: np.ndarray,
    states: list[str],
    path: str | os.PathLike,
    every: int | None = None,
    title: str | None = None,
) -> Path:
    """Write a PNG: left, ``frame`` (P, 3) in grey with the ``template`` (N, 3) drawn at
    every ``every``-th pose of the frames not lost (coloured from dark to light by frame);
    right, the per-frame ``fitness`` (F,) over the frame index, coloured by state.

    ``transforms``: (F, 4, 4) frame -> template (``register``'s convention); the template
    is drawn at their inverses, in frame coordinates. ``every``: None draws about 12.
    """
    plt = pyplot()
    count = len(transforms)
    every = every or max(1, count // 12)
    shown = [
        k
        for k in range(0, count, every)
        if states[k] != "lost" and np.isfinite(transforms[k]).all()
    ]
    fig = plt.figure(figsize=(12, 5), dpi=110)
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    drawn = display_points(template, 400)
    placed = [transform_points(np.linalg.inv(transforms[k]), drawn) for k in shown]
    scene = display_points(frame, 20_000)
    if placed:  # the frame around the path only: the object is small in a scene
        path_points = np.concatenate(placed)
        low, high = path_points.min(0), path_points.max(0)
        room = 0.5 * (high - low).max()
        scene = scene[((scene >= low - room) & (scene <= high + room)).all(1)]
    ax.scatter(*scene.T, s=1, c="0.75", label="first frame")
    colours = plt.get_cmap("viridis")(np.linspace(0, 0.9, max(len(shown), 1)))
    ends = {shown[0], shown[-1]} if shown else set()
    for k, points, colour in zip(shown, placed, colours, strict=False):
        ax.scatter(*points.T, s=2, color=colour, label=f"frame {k}" if k in ends else None)
    every_point = np.concatenate([scene, *placed]) if placed else scene
    mid = (every_point.max(0) + every_point.min(0)) / 2
    half = max((every_point.max(0) - every_point.min(0)).max() / 2, 1e-12)
    for axis, centre in zip("xyz", mid, strict=True):
        getattr(ax, f"set_{axis}lim")(centre - half, centre + half)
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=-70, azim=-90)  # about as a depth camera sees: z forward, y down
    ax.set_title(f"the template at the poses not lost, every {every} frames", fontsize=10)
    ax.legend(loc="upper left", fontsize=8, markerscale=4)
    curve = fig.add_subplot(1, 2, 2)
    frames = np.arange(count)
    curve.plot(frames, fitness, color="0.6", lw=1)
    for state, colour in STATE_COLOURS.items():
        pick = np.array([s == state for s in states], dtype=bool)
        if pick.any():
            curve.scatter(frames[pick], np.asarray(fitness)[pick], s=12, color=colour, label=state)
    curve.set_xlabel("frame")
    curve.set_ylabel("fit (share of the object's frame points within the inlier distance)")
    curve.set_ylim(-0.02, 1.02)
    curve.legend(fontsize=8)
    if title:
        fit_title(fig, title, fontsize=11)
    return _save(fig, path)

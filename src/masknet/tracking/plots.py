"""``trajectory.png``: a tracked object's path over the frames, and its fit over time."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from masknet.geometry.normals import least_spread_axis
from masknet.geometry.se3 import transform_points
from masknet.viz import _save, display_points, fit_title, pyplot

__all__ = ["STATE_COLOURS", "plot_trajectory", "view_axes"]

STATE_COLOURS = {
    "found": "tab:blue",
    "tracked": "tab:green",
    "refound": "tab:orange",
    "lost": "red",
}


def view_axes(points: np.ndarray, viewpoint: np.ndarray | None = None) -> np.ndarray:
    """(2, 3) orthonormal screen axes (right, up) for looking at ``points`` (P, 3): from
    ``viewpoint`` (3,) towards their centre, or, without one, along their direction of least
    spread (a floor is seen from above). Right is the world x axis on the screen's plane
    (y where x lies along the view), and up is such that a depth camera's frame (z forward,
    y down) is drawn as its image."""
    centre = points.mean(0)
    towards = None if viewpoint is None else centre - np.asarray(viewpoint, dtype=np.float64)
    if towards is not None and np.linalg.norm(towards) > 0:
        ahead = towards / np.linalg.norm(towards)
    else:
        ahead = least_spread_axis(points)
    world = np.eye(3)[0] if abs(ahead[0]) < 0.9 else np.eye(3)[1]
    right = world - (world @ ahead) * ahead
    right /= np.linalg.norm(right)
    return np.stack([right, np.cross(right, ahead)])


def plot_trajectory(
    template: np.ndarray,
    frame: np.ndarray,
    transforms: np.ndarray,
    fitness: np.ndarray,
    states: list[str],
    path: str | os.PathLike,
    every: int | None = None,
    title: str | None = None,
    viewpoint: np.ndarray | None = None,
) -> Path:
    """Write a PNG: left, the path seen from ``viewpoint`` (3,) (None: along the scene's
    least spread): ``frame`` (P, 3) in grey near the path, the ``template`` (N, 3) at every
    ``every``-th pose not lost (faint) and at the first and last (outlined), and the
    template's centre frame by frame, joined where no frame between was lost and coloured by
    state; right, the per-frame ``fitness`` (F,) over the frame index, coloured by state.

    ``transforms``: (F, 4, 4) frame -> template (``register``'s convention); the template
    is drawn at their inverses, in frame coordinates. ``every``: None draws about 12.
    """
    plt = pyplot()
    count = len(transforms)
    every = every or max(1, count // 12)
    kept = [k for k in range(count) if states[k] != "lost" and np.isfinite(transforms[k]).all()]
    poses = {k: np.linalg.inv(transforms[k]) for k in kept}
    drawn = display_points(template, 400)
    centres = {k: transform_points(poses[k], template.mean(0, keepdims=True))[0] for k in kept}
    scene = display_points(frame, 20_000)
    placed = {k: transform_points(poses[k], drawn) for k in kept[::every]}
    if kept:  # the frame around the path only: the object is small in a scene
        ends = {kept[0]: transform_points(poses[kept[0]], drawn)}
        ends[kept[-1]] = transform_points(poses[kept[-1]], drawn)
        around = np.concatenate([*ends.values(), np.array(list(centres.values()))])
        low, high = around.min(0), around.max(0)
        room = 0.5 * (high - low).max()
        scene = scene[((scene >= low - room) & (scene <= high + room)).all(1)]
    else:
        ends = {}
    axes = view_axes(scene if len(scene) >= 3 else drawn, viewpoint)
    fig = plt.figure(figsize=(12, 5), dpi=110)
    ax = fig.add_subplot(1, 2, 1)
    ax.scatter(*(scene @ axes.T).T, s=1, c="0.8", label="first frame")
    for points in placed.values():
        ax.scatter(*(points @ axes.T).T, s=1, color="0.55", alpha=0.35)
    for (k, points), colour in zip(ends.items(), ("tab:purple", "tab:olive"), strict=False):
        ax.scatter(*(points @ axes.T).T, s=2, color=colour, label=f"template at frame {k}")
    _draw_path(ax, centres, states, axes)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xticks([])
    ax.set_yticks([])
    seen = "from the viewpoint" if viewpoint is not None else "along the scene's least spread"
    ax.set_title(f"the object's centre frame by frame, seen {seen}", fontsize=10)
    ax.legend(loc="best", fontsize=8, markerscale=4)
    _draw_fit(fig.add_subplot(1, 2, 2), fitness, states)
    if title:
        fit_title(fig, title, fontsize=11)
    return _save(fig, path)


def _draw_path(ax, centres: dict[int, np.ndarray], states: list[str], axes: np.ndarray) -> None:
    """The centres (frame index -> (3,)) on the screen ``axes`` (2, 3): a line through
    consecutive frames, broken where frames were lost; a dot per frame in its state's
    colour; the first, last and each refound frame's index beside it."""
    frames = sorted(centres)
    if not frames:
        return
    screen = {k: centres[k] @ axes.T for k in frames}
    for a, b in zip(frames, frames[1:], strict=False):
        if b == a + 1:
            ax.plot(*np.stack([screen[a], screen[b]]).T, color="0.3", lw=1)
    for state, colour in STATE_COLOURS.items():
        pick = [k for k in frames if states[k] == state]
        if pick:
            ax.scatter(*np.stack([screen[k] for k in pick]).T, s=14, color=colour, zorder=3)
    for k in frames:
        if k in (frames[0], frames[-1]) or states[k] == "refound":
            ax.annotate(str(k), screen[k], fontsize=7, xytext=(3, 3), textcoords="offset points")


def _draw_fit(curve, fitness: np.ndarray, states: list[str]) -> None:
    """The per-frame fit (F,) over the frame index, a dot per frame in its state's colour."""
    frames = np.arange(len(fitness))
    curve.plot(frames, fitness, color="0.6", lw=1)
    for state, colour in STATE_COLOURS.items():
        pick = np.array([s == state for s in states], dtype=bool)
        if pick.any():
            curve.scatter(frames[pick], np.asarray(fitness)[pick], s=12, color=colour, label=state)
    curve.set_xlabel("frame")
    curve.set_ylabel("fit (share of the object's frame points within the inlier distance)")
    curve.set_ylim(-0.02, 1.02)
    curve.legend(fontsize=8)

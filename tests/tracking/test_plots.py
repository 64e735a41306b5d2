"""trajectory.png (masknet.tracking.plots): the screen axes and the picture of a path."""

from __future__ import annotations

import numpy as np
import pytest

from masknet.tracking.plots import plot_trajectory, view_axes


def test_a_depth_frame_seen_from_its_camera_is_drawn_as_its_image():
    """z forward, y down: right is x, up is -y."""
    points = np.random.default_rng(0).normal(size=(200, 3))
    points += [0, 0, 5] - points.mean(0)  # centred straight ahead of the camera
    right, up = view_axes(points, np.zeros(3))
    assert np.allclose(right, [1, 0, 0], atol=1e-9)
    assert np.allclose(up, [0, -1, 0], atol=1e-9)


def test_without_a_viewpoint_a_floor_is_seen_from_above():
    """The direction of least spread is the one looked along: both screen axes lie in the
    floor's plane."""
    rng = np.random.default_rng(1)
    floor = np.column_stack(
        [rng.uniform(-2, 2, 500), rng.normal(0, 0.01, 500), rng.uniform(-2, 2, 500)]
    )
    axes = view_axes(floor)
    assert np.abs(axes[:, 1]).max() < 0.05
    assert np.allclose(axes @ axes.T, np.eye(2), atol=1e-9)


def test_a_path_with_lost_frames_is_drawn(tmp_path):
    pytest.importorskip("matplotlib")
    rng = np.random.default_rng(2)
    template = rng.normal(size=(300, 3))
    transforms = np.repeat(np.eye(4)[None], 6, axis=0)
    transforms[:, 0, 3] = -np.arange(6) * 0.1  # frame -> template: the object moves along +x
    transforms[3] = np.nan  # a lost frame has no pose
    states = ["found", "tracked", "tracked", "lost", "refound", "tracked"]
    out = plot_trajectory(
        template,
        rng.normal(size=(1000, 3)),
        transforms,
        [1, 0.9, 0.9, 0, 0.8, 0.9],
        states,
        tmp_path / "t.png",
        viewpoint=np.array([0.0, 0.0, -10.0]),
    )
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000

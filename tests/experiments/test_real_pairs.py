"""masknet.experiments.real_pairs: the room picture and the odometry guess."""

from __future__ import annotations

import numpy as np
import pytest

from masknet.experiments.real_pairs import plot_rooms, room_odometry


def test_the_odometry_guess_is_the_published_turn_and_shift():
    pose = room_odometry()
    assert np.degrees(np.arctan2(pose[1, 0], pose[0, 0])) == pytest.approx(39.71, abs=0.01)
    assert np.allclose(pose[:3, 3], [1.79387, 0.720047, 0.0])
    assert np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3))


def test_the_room_picture_has_a_panel_per_pose(tmp_path):
    pytest.importorskip("matplotlib")
    rng = np.random.default_rng(0)
    room = np.c_[rng.uniform(-5, 5, (4000, 2)), rng.uniform(0, 3, 4000)]
    path = tmp_path / "rooms.png"
    plot_rooms(room, room, {"as given": np.eye(4), "moved": room_odometry()}, path)
    from PIL import Image

    width, height = Image.open(path).size
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert width > 1.7 * height  # two panels side by side

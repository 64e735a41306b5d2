"""Benchmark sequences: the truth moves the object's frame points onto the template, the wall
hides it, the jump turns it, and the scenes are sensor-sized."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.geometry.se3 import rotation_angle_deg
from masknet.tracking.sequences import SequenceConfig, make_sequence


@pytest.fixture(scope="module")
def sequence():
    shapes = load_modelnet40(bundled_sample_path(), "test").points
    config = SequenceConfig(frames=8, occlusion_at=0.25, occlusion_frames=2, jump_at=0.75)
    return make_sequence(shapes[24], list(shapes[40:43]), config, seed=0, name="chair")


def _on_object(seq, k):
    moved = seq.frames[k] @ seq.truth[k][:3, :3].T + seq.truth[k][:3, 3]
    return int((cKDTree(seq.template).query(moved)[0] < 0.03).sum())


def test_the_truth_puts_the_object_on_the_template_unless_hidden(sequence):
    assert list(np.flatnonzero(sequence.occluded)) == [2, 3] and sequence.jump == 6
    seen = [_on_object(sequence, k) for k in range(8)]
    assert all(n > 250 for k, n in enumerate(seen) if k not in (2, 3)), seen
    assert seen[2] < 20 and seen[3] < 20, seen  # behind the wall
    assert all(3000 <= len(frame) <= 20_000 for frame in sequence.frames)


def test_the_object_moves_smoothly_then_jumps(sequence):
    steps = [sequence.truth[k + 1] @ np.linalg.inv(sequence.truth[k]) for k in range(7)]
    degrees = [float(rotation_angle_deg(step[:3, :3])) for step in steps]
    assert all(d <= 3.01 for k, d in enumerate(degrees) if k != 5), degrees
    assert degrees[5] == pytest.approx(30, abs=3.1)  # frame 5 -> 6: the jump


def test_one_seed_gives_one_sequence():
    shapes = load_modelnet40(bundled_sample_path(), "test").points
    config = SequenceConfig(frames=2, occlusion_frames=0, clutter=1)
    one, two = (make_sequence(shapes[24], [shapes[40]], config, seed=5) for _ in range(2))
    assert np.array_equal(one.frames[1], two.frames[1]) and np.array_equal(one.truth, two.truth)

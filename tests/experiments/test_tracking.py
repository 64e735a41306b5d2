"""The tracking experiment's figures: a perfect answer, a wrong confident one, a silent one."""

from __future__ import annotations

import numpy as np
import pytest

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.experiments.tracking import score
from masknet.tracking.sequences import SequenceConfig, make_sequence


@pytest.fixture(scope="module")
def sequence():
    shapes = load_modelnet40(bundled_sample_path(), "test").points
    config = SequenceConfig(frames=6, occlusion_at=0.3, occlusion_frames=2, jump_at=0.7, clutter=1)
    return make_sequence(shapes[24], [shapes[40]], config, seed=0)


def test_the_truth_scores_all_within_and_a_shifted_pose_none(sequence):
    truth = [(t, True, 0.01 * (1 + k), k > 0) for k, t in enumerate(sequence.truth)]
    row = score(sequence, truth)
    assert row["within"] == 1 and row["frames_to_refind"] == 0 and row["trusted_wrong"] == 0
    assert row["hidden_not_trusted"] == 0 and row["ms_per_frame"] == pytest.approx(35)
    assert row["median_ms"] == pytest.approx(40)  # frames 1-5 timed: 20-60 ms
    sizes = [len(f) for f in sequence.frames]
    assert row["scene_points"] == [min(sizes), max(sizes)]
    shifted = np.array(sequence.truth)
    shifted[:, :3, 3] += 0.3  # 30% of the radius off, and trusted
    row = score(sequence, [(t, True, 0.0, True) for t in shifted])
    assert row["within"] == 0 and row["frames_to_refind"] is None and row["trusted_wrong"] == 1


def test_no_pose_on_the_hidden_frames_counts_as_honest(sequence):
    answers = [
        (np.full((4, 4), np.nan), False, 0.0, True) if hidden else (t, True, 0.0, True)
        for t, hidden in zip(sequence.truth, sequence.occluded, strict=True)
    ]
    row = score(sequence, answers)
    assert row["hidden_not_trusted"] == 1 and row["within"] == 1 and row["trusted_wrong"] == 0

"""masknet.registration.hypotheses: scored poses, their order, one per basin."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from masknet.registration.hypotheses import Scored, distinct, rank, rotation_between_deg


def _pose(degrees: float, shift: float = 0.0) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("z", degrees, degrees=True).as_matrix()
    pose[0, 3] = shift
    return pose


def test_the_angle_between_two_poses():
    assert abs(rotation_between_deg(_pose(10), _pose(35)) - 25) < 1e-9
    assert rotation_between_deg(_pose(0, 5.0), _pose(0, -3.0)) == 0  # translation is not rotation


def test_rank_prefers_score_then_fitness_then_lower_rmse():
    a = Scored(0.9, 0.02, 0.50, _pose(0), "a")
    b = Scored(0.8, 0.01, 0.50, _pose(0), "b")
    c = Scored(0.8, 0.03, 0.50, _pose(0), "c")
    d = Scored(0.1, 0.09, 0.60, _pose(0), "d")
    assert [s.kind for s in sorted([c, b, a, d], key=rank, reverse=True)] == ["d", "a", "b", "c"]


def test_distinct_keeps_one_pose_per_basin():
    scored = [
        Scored(1, 0, 1, _pose(0), "best"),
        Scored(1, 0, 1, _pose(1), "same basin"),  # 1 degree, same place
        Scored(1, 0, 1, _pose(1, 0.5), "moved"),  # 1 degree but 0.5 away
        Scored(1, 0, 1, _pose(30), "turned"),
    ]
    kept = distinct(scored, count=5, limit=0.2, degrees=2.0)
    assert [s.kind for s in kept] == ["best", "moved", "turned"]
    assert [s.kind for s in distinct(scored, count=2, limit=0.2)] == ["best", "moved"]

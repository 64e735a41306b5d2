"""masknet.registration.judge.hypotheses: the angle between two poses, and the old names of the
scored hypotheses (now the arbiter's Candidate, rank and one_per_basin)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from masknet.registration.judge import arbiter, hypotheses
from masknet.registration.judge.hypotheses import rotation_between_deg


def _pose(degrees: float, shift: float = 0.0) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("z", degrees, degrees=True).as_matrix()
    pose[0, 3] = shift
    return pose


def test_the_angle_between_two_poses():
    assert abs(rotation_between_deg(_pose(10), _pose(35)) - 25) < 1e-9
    assert rotation_between_deg(_pose(0, 5.0), _pose(0, -3.0)) == 0  # translation is not rotation


def test_the_old_scored_hypotheses_still_work_with_a_warning():
    with pytest.warns(DeprecationWarning, match="arbiter.Candidate"):
        scored = hypotheses.Scored
    entry = scored(0.9, 0.02, 0.5, _pose(0), "fpfh")
    assert isinstance(entry, arbiter.Candidate)
    assert (entry.fitness, entry.rmse, entry.score, entry.kind) == (0.9, 0.02, 0.5, "fpfh")
    with pytest.warns(DeprecationWarning, match="arbiter.one_per_basin"):
        assert hypotheses.distinct is arbiter.one_per_basin
    with pytest.warns(DeprecationWarning, match="arbiter.rank"):
        assert hypotheses.rank is arbiter.rank
    with pytest.raises(AttributeError):
        hypotheses.no_such_name  # noqa: B018

"""RegistrationResult: Open3D's names beside masknet's, and the rotation's angle."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from masknet.registration.terms.result import RegistrationResult


def result(transform: np.ndarray, info: dict | None = None) -> RegistrationResult:
    return RegistrationResult(
        R=transform[..., :3, :3], t=transform[..., :3, 3], transform=transform, mask=None,
        info=info or {},
    )  # fmt: skip


def test_open3d_names_read_the_same_values():
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_rotvec([0.0, 0.0, 0.5]).as_matrix()
    found = result(pose, {"fitness": np.array(0.8), "inlier_rmse": np.array(0.01)})
    assert found.transformation is found.transform
    assert found.fitness == 0.8 and found.inlier_rmse == 0.01
    assert result(pose).fitness is None  # not reported: None, not a guess


def test_rotation_deg_single_and_batched():
    angles = [1e-7, 30.0, 179.9]
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, :3, :3] = Rotation.from_rotvec(
        np.radians(angles)[:, None] * [[0.0, 0.6, 0.8]]
    ).as_matrix()
    np.testing.assert_allclose(result(poses).rotation_deg, angles, rtol=1e-6)
    assert result(poses[1]).rotation_deg == pytest.approx(30.0)


@pytest.mark.parametrize(("value", "expected"), [(np.bool_(True), True), (None, None)])
def test_converged_is_a_bool_for_one_pair(value, expected):
    info = {} if value is None else {"converged": value}
    assert result(np.eye(4), info).converged is expected
    if value is not None:
        batch = result(np.tile(np.eye(4), (2, 1, 1)), {"converged": np.array([True, False])})
        np.testing.assert_array_equal(batch.converged, [True, False])

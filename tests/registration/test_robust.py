"""masknet.registration.robust: rotation hypotheses, scoring, and the unit-free result."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from masknet import MaskNetError, register
from masknet.data import bundled_sample_path, load_modelnet40
from masknet.evaluation.registration import pose_errors
from masknet.registration.robust import hypothesis_rotations


@pytest.fixture(scope="module")
def far_pair():
    """A 70% view of a sample shape, turned by 150 degrees and moved, with 8% outliers."""
    shape = load_modelnet40(bundled_sample_path(), "test").points[3].astype(np.float64)
    part = shape[np.argsort(shape @ np.array([0.3, 0.8, 0.5]))[: int(0.7 * len(shape))]]
    rot = Rotation.from_rotvec(np.radians(150) * np.array([0.0, 0.6, 0.8])).as_matrix()
    shift = np.array([0.4, -0.2, 0.3])
    outliers = np.random.default_rng(0).uniform(-1, 1, size=(60, 3))
    source = np.concatenate([part, outliers]) @ rot.T + shift
    truth = np.eye(4)  # source -> template
    truth[:3, :3], truth[:3, 3] = rot.T, -rot.T @ shift
    return shape, source, truth


def test_hypotheses_are_distinct_rotations_identity_first():
    rots = hypothesis_rotations(24)
    assert rots.shape == (24, 3, 3)
    np.testing.assert_allclose(rots[0], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(rots), 1, atol=1e-9)
    gaps = np.linalg.norm(rots[:, None] - rots[None], axis=(2, 3)) + 10 * np.eye(24)
    assert gaps.min() > 1.0  # no two alike
    assert hypothesis_rotations(30).shape == (30, 3, 3)


def test_robust_recovers_a_far_rotation_where_icp_stops_short(far_pair):
    template, source, truth = far_pair
    icp_rot, _ = pose_errors(register(template, source).transform[None], truth[None])
    result = register(template, source, method="robust")
    rot, trans = pose_errors(result.transform[None], truth[None])
    assert icp_rot[0] > 20 and rot[0] < 2 and trans[0] < 0.05
    assert result.source_mask is not None and result.source_mask[-60:].mean() < 0.5
    assert {"hypothesis", "score", "fitness", "inlier_rmse"} <= set(result.info)


def test_millimetres_and_metres_give_the_same_transform(far_pair):
    template, source, _ = far_pair
    for kwargs in ({"method": "robust"}, {"method": "icp", "max_iterations": 40}):
        metres = register(template, source, precision="fp32", **kwargs)
        millimetres = register(1000 * template, 1000 * source, precision="fp32", **kwargs)
        np.testing.assert_allclose(millimetres.R, metres.R, atol=1e-5)
        np.testing.assert_allclose(millimetres.t, 1000 * metres.t, atol=1e-2)


def test_robust_options_are_checked(far_pair):
    template, source, _ = far_pair
    with pytest.raises(MaskNetError, match="candidates"):
        register(template, source, method="robust", candidates=0)
    with pytest.raises(MaskNetError, match="trim"):
        register(template, source, method="robust", trim=1.5)
    with pytest.raises(MaskNetError, match="unknown option|not an option|option"):
        register(template, source, method="robust", voxel_size=0.05)


def test_robust_option_names_match_the_options_table():
    from masknet.registration import RobustOptions
    from masknet.registration.methods import OPTIONS

    assert set(OPTIONS["robust"]) == set(RobustOptions._fields)


def test_trimmed_mean_over_valid_entries():
    from masknet.registration.robust import trimmed_mean

    d2 = np.array([[4.0, 1.0, 9.0, 2.0], [5.0, 7.0, 3.0, 1.0]])
    np.testing.assert_allclose(trimmed_mean(d2, 0.5), [1.5, 2.0])
    valid = np.array([[True, False, True, True], [False, False, False, False]])
    # Row 0 keeps round(0.5 * 3) = 2 of {4, 9, 2}: (2 + 4) / 2; row 1 has nothing valid.
    np.testing.assert_allclose(trimmed_mean(d2, 0.5, valid), [3.0, np.inf])

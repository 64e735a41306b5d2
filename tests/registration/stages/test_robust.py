"""masknet.registration.stages.robust and .auto: the coarse-to-fine pipeline and the default."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from masknet import MaskNetError, register
from masknet.data import bundled_sample_path, load_modelnet40
from masknet.evaluation.registration import pose_errors
from masknet.geometry.se3 import hypothesis_rotations
from masknet.registration.terms.methods import default_method
from masknet.registration.terms.result import AUTO_INFO, PIPELINE_INFO


def _pair(shape: np.ndarray, degrees: float, outliers: int, seed: int = 0):
    """A 70% view of ``shape``, turned by ``degrees`` and moved, with uniform outliers;
    returns template, source and the true source -> template transform."""
    part = shape[np.argsort(shape @ np.array([0.3, 0.8, 0.5]))[: int(0.7 * len(shape))]]
    rot = Rotation.from_rotvec(np.radians(degrees) * np.array([0.0, 0.6, 0.8])).as_matrix()
    shift = np.array([0.4, -0.2, 0.3])
    noise = np.random.default_rng(seed).uniform(-1, 1, size=(outliers, 3))
    source = np.concatenate([part, noise]) @ rot.T + shift
    truth = np.eye(4)
    truth[:3, :3], truth[:3, 3] = rot.T, -rot.T @ shift
    return shape, source, truth


@pytest.fixture(scope="module")
def shapes():
    return load_modelnet40(bundled_sample_path(), "test").points.astype(np.float64)


@pytest.fixture(scope="module")
def far_pair(shapes):
    """A 70% view of a sample shape, turned by 150 degrees and moved, with 8% outliers."""
    return _pair(shapes[3], 150.0, 60)


def test_hypotheses_are_distinct_rotations_identity_first():
    rots = hypothesis_rotations(24)
    assert rots.shape == (24, 3, 3)
    np.testing.assert_allclose(rots[0], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(rots), 1, atol=1e-9)
    gaps = np.linalg.norm(rots[:, None] - rots[None], axis=(2, 3)) + 10 * np.eye(24)
    assert gaps.min() > 1.0  # no two alike
    assert hypothesis_rotations(30).shape == (30, 3, 3)


@pytest.mark.parametrize("method", ["robust", "auto"])
def test_a_far_rotation_with_outliers_where_icp_stops_short(far_pair, method):
    template, source, truth = far_pair
    icp = register(template, source, method="icp")
    icp_rot, _ = pose_errors(icp.transform[None], truth[None])
    result = register(template, source, method=method)
    rot, trans = pose_errors(result.transform[None], truth[None])
    assert icp_rot[0] > 20 and rot[0] < 0.5 and trans[0] < 0.01
    assert str(result.info["path"]) != "fast"  # Mask-ICP alone cannot get there
    assert result.info["fitness"] > 0.97 and not result.info["ambiguous"]


def test_the_default_is_auto_and_takes_the_fast_path_on_an_easy_pair(shapes):
    template, source, truth = _pair(shapes[3], 10.0, 0)
    result = register(template, source)
    rot, trans = pose_errors(result.transform[None], truth[None])
    assert rot[0] < 0.01 and trans[0] < 1e-3
    assert str(result.info["path"]) == "fast" and np.isnan(result.info["escalated_fitness"])
    assert list(result.info) == list(AUTO_INFO)  # the one list of the keys, in its order


def test_escalation_says_why(far_pair):
    template, source, _ = far_pair
    result = register(template, source)
    assert str(result.info["path"]).startswith("robust/")
    assert result.info["escalated_fitness"] < 0.99 <= result.info["fitness"] + 0.02
    assert list(result.info) == list(AUTO_INFO)


def test_robust_reports_the_pipeline_info_and_auto_adds_one_key(shapes):
    template, source, _ = _pair(shapes[3], 10.0, 0)
    result = register(template, source, method="robust")
    assert list(result.info) == list(PIPELINE_INFO)
    assert AUTO_INFO == (*PIPELINE_INFO, "escalated_fitness")
    assert result.info["runner_up"].shape == (4, 4)  # NaN where there is none


def _box_surface(seed: int, count: int) -> np.ndarray:
    """``count`` points on the surface of a 2 x 1 x 1 box (square cross-section)."""
    half = np.array([1.0, 0.5, 0.5])
    points = np.random.default_rng(seed).uniform(-1, 1, (count, 3)) * half
    face = np.abs(points / half).argmax(1)  # pushed out to its nearest face
    points[np.arange(count), face] = np.sign(points[np.arange(count), face]) * half[face]
    return points


def test_a_symmetric_flip_is_reported_as_ambiguous():
    """Two independent samples of a box with a square cross-section, one turned by 90
    degrees about the long axis: every quarter turn fits as well, so the result must say
    the answer is ambiguous and give a runner-up that fits as well."""
    template = _box_surface(0, 1024)
    turn = Rotation.from_euler("x", 90, degrees=True).as_matrix()
    source = _box_surface(1, 700) @ turn.T
    for method in ("robust", None):
        result = register(template, source, method=method)
        assert result.info["ambiguous"]
        runner_up = result.info["runner_up"]
        assert np.isfinite(runner_up).all()
        angle = np.degrees(Rotation.from_matrix(runner_up[:3, :3] @ result.R.T).magnitude())
        assert angle > 45  # another answer, not the same one twice
        assert result.info["runner_up_fitness"] >= result.info["fitness"] - 0.02


def test_millimetres_and_metres_give_the_same_transform(far_pair):
    template, source, _ = far_pair
    for kwargs in ({"method": "robust"}, {}, {"method": "icp", "max_iterations": 40}):
        metres = register(template, source, precision="fp32", **kwargs)
        millimetres = register(1000 * template, 1000 * source, precision="fp32", **kwargs)
        # ICP's relative stopping rule may stop an iteration apart: 0.01 degrees, 0.1 mm.
        mm = millimetres.transform.copy()
        mm[:3, 3] /= 1000
        rot, trans = pose_errors(mm[None], metres.transform[None])
        assert rot[0] < 0.01 and trans[0] < 1e-4, kwargs


def test_robust_options_are_checked(far_pair):
    template, source, _ = far_pair
    with pytest.raises(MaskNetError, match="candidates"):
        register(template, source, method="robust", candidates=0)
    with pytest.raises(MaskNetError, match="accept_fitness"):
        register(template, source, method="robust", accept_fitness=1.5)
    with pytest.raises(MaskNetError, match="unknown option"):
        register(template, source, method="robust", voxel_size=0.05)


def test_a_named_method_is_the_method():
    assert default_method(None, None) == "auto"
    assert default_method("robust", None) == "robust"


def test_auto_and_robust_take_the_robust_options():
    from masknet.registration import RobustOptions
    from masknet.registration.terms.methods import METHOD_TABLE

    assert METHOD_TABLE["robust"].options is RobustOptions is METHOD_TABLE["auto"].options


def test_trimmed_mean_over_valid_entries():
    from masknet.geometry.trimmed import trimmed_mean

    d2 = np.array([[4.0, 1.0, 9.0, 2.0], [5.0, 7.0, 3.0, 1.0]])
    np.testing.assert_allclose(trimmed_mean(d2, 0.5), [1.5, 2.0])
    valid = np.array([[True, False, True, True], [False, False, False, False]])
    # Row 0 keeps round(0.5 * 3) = 2 of {4, 9, 2}: (2 + 4) / 2; row 1 has nothing valid.
    np.testing.assert_allclose(trimmed_mean(d2, 0.5, valid), [3.0, np.inf])


@pytest.mark.usefixtures("one_thread")
@pytest.mark.parametrize("method", ["robust", None])
def test_rotations_to_180_and_outliers_on_sample_pairs(shapes, method):
    """30 seeded pairs per set (70% views). Measured, the same for robust and the default:
    rotations to 180 deg: 29 pairs within 2e-6 deg, one 114 deg off and reported as
    ambiguous; 10% outliers: mean 0.040 deg, worst 0.10 deg. (Without the fast path's
    settling of a fitting pose still moving, the default's pair 16 stopped 0.23 deg off.)"""
    from masknet.data import PairConfig, make_test_pairs

    for config in (PairConfig(max_angle_deg=180), PairConfig(outlier_ratio=0.1)):
        pairs = make_test_pairs(shapes.astype(np.float32), 30, config, seed=31)
        truth = pairs.transform.double().numpy()
        errors, ambiguous = [], []
        for i in range(30):
            result = register(pairs.template[i].numpy(), pairs.source[i].numpy(), method=method)
            errors.append(pose_errors(result.transform[None], truth[i : i + 1])[0][0])
            ambiguous.append(bool(result.info["ambiguous"]))
        errors, ambiguous = np.array(errors), np.array(ambiguous)
        if config.outlier_ratio:
            assert errors.mean() < 0.08 and errors.max() < 0.25, errors
        else:  # every large error is flagged, and few are
            assert ambiguous.sum() <= 2 and errors[~ambiguous].max() < 0.01, (errors, ambiguous)

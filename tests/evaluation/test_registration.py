"""The registration benchmark: error definitions and tables."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.evaluation.registration import (
    benchmark_registration,
    iteration_errors,
    pose_errors,
    summarize_errors,
)
from masknet.geometry import make_transform, so3_exp

pytestmark = pytest.mark.usefixtures("one_thread")


def test_pose_errors_are_the_angle_and_the_translation_distance():
    truth = np.eye(4)[None].repeat(2, 0)
    rot = so3_exp(
        torch.tensor([[0.0, 0.0, np.radians(30.0)], [0.0, 0.0, 0.0]], dtype=torch.float64)
    )
    estimate = make_transform(
        rot, torch.tensor([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0]], dtype=torch.float64)
    )
    rotation, translation = pose_errors(estimate.numpy(), truth)
    np.testing.assert_allclose(rotation, [30.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(translation, [0.0, 5.0])
    summary = summarize_errors(rotation, translation)
    assert summary["rot_mean"] == pytest.approx(15.0)
    assert summary["rot_rmse"] == pytest.approx(np.sqrt(450.0))
    assert summary["trans_median"] == pytest.approx(2.5)


@pytest.fixture(scope="module")
def pairs():
    shapes = load_modelnet40(bundled_sample_path()).points[:3]
    return make_test_pairs(shapes, 3, PairConfig(max_angle_deg=20), seed=0)


def test_benchmark_rows_and_more_iterations_help(pairs):
    pipelines = {
        "ICP 1": {"method": "icp", "use_mask": False, "max_iterations": 1},
        "ICP 30": {"method": "icp", "use_mask": False, "max_iterations": 30},
    }
    rows = benchmark_registration(pairs, pipelines, progress=False)
    assert set(rows) == set(pipelines)
    assert {"rot_mean", "rot_median", "rot_rmse", "trans_mean", "ms_per_pair", "ms_mask"} <= set(
        rows["ICP 1"]
    )
    assert rows["ICP 30"]["rot_mean"] < rows["ICP 1"]["rot_mean"]
    assert rows["ICP 1"]["ms_mask"] == 0 and rows["ICP 1"]["ms_per_pair"] > 0


def test_iteration_rows_follow_the_rounds(pairs):
    rows = iteration_errors(
        pairs, rounds=3, progress=False, use_mask=False, method="icp", max_iterations=2
    )
    assert [r["round"] for r in rows] == [1, 2, 3]
    # Plain ICP continued: each round is two more iterations, so errors do not grow.
    assert rows[2]["rot_mean"] <= rows[0]["rot_mean"] + 1e-9


def test_pose_errors_of_single_transforms_and_of_batches():
    from scipy.spatial.transform import Rotation

    from masknet.errors import MaskNetError
    from masknet.evaluation.registration import pose_errors

    turned = np.eye(4)
    turned[:3, :3] = Rotation.from_rotvec([0.0, 0.0, np.radians(30)]).as_matrix()
    turned[:3, 3] = [0.3, 0.4, 0.0]
    rotation, translation = pose_errors(turned, np.eye(4))
    assert np.ndim(rotation) == 0 and rotation == pytest.approx(30.0)
    assert translation == pytest.approx(0.5)
    rotations, translations = pose_errors(np.stack([turned, np.eye(4)]), np.stack([np.eye(4)] * 2))
    np.testing.assert_allclose(rotations, [30.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(translations, [0.5, 0.0])
    with pytest.raises(MaskNetError, match="one shape"):
        pose_errors(turned, np.stack([turned] * 2))

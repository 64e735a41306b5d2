"""Tests for masknet.geometry.align: rigid_align (weighted Kabsch, no scale) and centroids."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from masknet.geometry import (
    random_rotation,
    rigid_align,
    transform_points,
)
from masknet.geometry.align import rigid_transforms_numpy
from masknet.geometry.se3 import make_transform, so3_exp


def _problem(b: int, p: int, seed: int = 0, max_angle_deg: float = 180.0):
    g = torch.Generator().manual_seed(seed)
    source = torch.randn(b, p, 3, generator=g, dtype=torch.float64)
    rot = random_rotation(b, max_angle_deg, g, dtype=torch.float64)
    trans = torch.randn(b, 3, generator=g, dtype=torch.float64)
    target = transform_points(make_transform(rot, trans), source)
    return source, target, rot, trans


def test_recovers_known_transform_exactly():
    source, target, rot, trans = _problem(4, 50, seed=1)
    r, t = rigid_align(source, target)
    assert r.shape == (4, 3, 3) and t.shape == (4, 3) and r.dtype == torch.float64
    torch.testing.assert_close(r, rot, atol=1e-12, rtol=0)
    torch.testing.assert_close(t, trans, atol=1e-12, rtol=0)


def test_float32_in_float32_out():
    source, target, rot, trans = _problem(3, 40, seed=2)
    r, t = rigid_align(source.float(), target.float())
    assert r.dtype == torch.float32 and t.dtype == torch.float32
    torch.testing.assert_close(r, rot.float(), atol=1e-5, rtol=0)
    torch.testing.assert_close(t, trans.float(), atol=1e-5, rtol=0)


def test_zero_weights_ignore_outliers():
    source, target, rot, trans = _problem(2, 60, seed=3)
    g = torch.Generator().manual_seed(3)
    corrupted = target.clone()
    corrupted[:, :15] += 10 * torch.randn(2, 15, 3, generator=g, dtype=torch.float64)
    weights = torch.ones(2, 60, dtype=torch.float64)
    weights[:, :15] = 0
    r, t = rigid_align(source, corrupted, weights)
    torch.testing.assert_close(r, rot, atol=1e-12, rtol=0)
    torch.testing.assert_close(t, trans, atol=1e-12, rtol=0)
    r_bad, _ = rigid_align(source, corrupted)  # unweighted: the outliers pull it off
    assert (r_bad - rot).abs().max() > 1e-3


def test_weights_are_scale_free_and_match_the_subset():
    source, target, _, _ = _problem(2, 30, seed=4)
    g = torch.Generator().manual_seed(4)
    target = target + 0.05 * torch.randn(target.shape, generator=g, dtype=torch.float64)
    keep = torch.zeros(2, 30, dtype=torch.bool)
    keep[:, ::3] = True
    r1, t1 = rigid_align(source, target, keep.double())
    r2, t2 = rigid_align(source, target, 7.5 * keep.double())
    r3, t3 = rigid_align(source[:, ::3], target[:, ::3])
    torch.testing.assert_close(r1, r2)
    torch.testing.assert_close(t1, t2)
    torch.testing.assert_close(r1, r3)
    torch.testing.assert_close(t1, t3)


def test_planar_input_gives_a_rotation_not_a_reflection():
    source, _, rot, trans = _problem(3, 40, seed=5)
    source[..., 2] = 0  # all points on a plane: one singular value is zero
    target = transform_points(make_transform(rot, trans), source)
    r, t = rigid_align(source, target)
    torch.testing.assert_close(torch.linalg.det(r), torch.ones(3, dtype=torch.float64))
    torch.testing.assert_close(r, rot, atol=1e-10, rtol=0)
    torch.testing.assert_close(t, trans, atol=1e-10, rtol=0)


def test_mirrored_target_still_gives_det_plus_one():
    source, _, _, _ = _problem(2, 25, seed=6)
    mirrored = source * torch.tensor([1.0, 1.0, -1.0], dtype=torch.float64)
    r, _ = rigid_align(source, mirrored)
    torch.testing.assert_close(torch.linalg.det(r), torch.ones(2, dtype=torch.float64))
    torch.testing.assert_close(
        r @ r.transpose(1, 2), torch.eye(3, dtype=torch.float64).expand(2, 3, 3)
    )


def test_zero_total_weight_gives_identity():
    source, target, rot, trans = _problem(2, 10, seed=7)
    weights = torch.ones(2, 10, dtype=torch.float64)
    weights[1] = 0
    r, t = rigid_align(source, target, weights)
    torch.testing.assert_close(r[0], rot[0], atol=1e-12, rtol=0)
    torch.testing.assert_close(t[0], trans[0], atol=1e-12, rtol=0)
    torch.testing.assert_close(r[1], torch.eye(3, dtype=torch.float64))
    torch.testing.assert_close(t[1], torch.zeros(3, dtype=torch.float64))


def test_bad_shapes_raise():
    source, target, _, _ = _problem(2, 10)
    with pytest.raises(ValueError):
        rigid_align(source, target[:, :9])
    with pytest.raises(ValueError):
        rigid_align(source[0], target[0])
    with pytest.raises(ValueError):
        rigid_align(source, target, torch.ones(2, 9))


def test_numpy_rigid_transform_matches_rigid_align_and_never_reflects():
    rng = np.random.default_rng(7)
    source = rng.normal(size=(50, 3))
    target = source @ so3_exp(torch.tensor([0.4, -0.3, 1.1])).numpy().T + [1.0, -2.0, 0.5]
    target += rng.normal(0, 0.01, target.shape)
    rot, trans = rigid_align(torch.from_numpy(source)[None], torch.from_numpy(target)[None])
    transform = rigid_transforms_numpy(source[None], target[None])[0]
    np.testing.assert_allclose(transform[:3, :3], rot[0].numpy(), atol=1e-10)
    np.testing.assert_allclose(transform[:3, 3], trans[0].numpy(), atol=1e-10)
    mirrored = source * [1, 1, -1]  # the best orthogonal map is a reflection
    assert np.linalg.det(rigid_transforms_numpy(source[None], mirrored[None])[0, :3, :3]) > 0


def test_batched_numpy_solve_equals_the_torch_solve_and_recovers_the_motion():
    rng = np.random.default_rng(0)
    source = rng.normal(size=(5, 40, 3))
    rot = Rotation.random(5, random_state=1).as_matrix()
    target = source @ rot.transpose(0, 2, 1) + rng.normal(size=(5, 1, 3))
    batched = rigid_transforms_numpy(source, target)
    torch_rot, torch_t = rigid_align(torch.from_numpy(source), torch.from_numpy(target))
    np.testing.assert_allclose(batched[:, :3, :3], torch_rot.numpy(), atol=1e-10)
    np.testing.assert_allclose(batched[:, :3, 3], torch_t.numpy(), atol=1e-10)
    np.testing.assert_allclose(batched[:, :3, :3], rot, atol=1e-10)


def test_weights_drop_rows_and_no_weight_gives_the_identity():
    rng = np.random.default_rng(2)
    source = rng.normal(size=(2, 30, 3))
    rot = Rotation.from_euler("z", 40, degrees=True).as_matrix()
    target = source @ rot.T
    target[0, :10] += 5.0  # outliers, weighted out
    weights = np.ones((2, 30))
    weights[0, :10] = 0
    weights[1] = 0
    out = rigid_transforms_numpy(source, target, weights)
    np.testing.assert_allclose(out[0, :3, :3], rot, atol=1e-10)
    np.testing.assert_allclose(out[1], np.eye(4), atol=1e-12)

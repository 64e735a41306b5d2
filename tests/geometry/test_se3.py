"""Tests for masknet.geometry.se3: exponential maps, inverses, conventions, angles."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from masknet.geometry.se3 import (
    invert_transform,
    make_transform,
    random_rotation,
    rotation_angle,
    rotation_error_deg,
    se3_exp,
    skew,
    so3_exp,
    split_transform,
    transform_points,
    translation_error,
)


def _rotvecs(n: int, seed: int = 0, max_angle: float = math.pi) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    axis = torch.randn(n, 3, generator=g, dtype=torch.float64)
    axis = axis / axis.norm(dim=-1, keepdim=True)
    angle = torch.rand(n, 1, generator=g, dtype=torch.float64) * max_angle
    return axis * angle


def test_skew_is_cross_product():
    g = torch.Generator().manual_seed(1)
    a = torch.randn(5, 3, generator=g, dtype=torch.float64)
    b = torch.randn(5, 3, generator=g, dtype=torch.float64)
    got = (skew(a) @ b[..., None])[..., 0]
    torch.testing.assert_close(got, torch.linalg.cross(a, b))


def test_so3_exp_orthonormal_with_unit_determinant():
    rot = so3_exp(_rotvecs(64))
    eye = torch.eye(3, dtype=torch.float64).expand_as(rot)
    torch.testing.assert_close(rot @ rot.transpose(-1, -2), eye, atol=1e-12, rtol=0)
    torch.testing.assert_close(torch.linalg.det(rot), torch.ones(64, dtype=torch.float64))


def test_so3_exp_matches_scipy_from_rotvec():
    omega = _rotvecs(64, seed=3)
    expected = torch.from_numpy(Rotation.from_rotvec(omega.numpy()).as_matrix())
    torch.testing.assert_close(so3_exp(omega), expected, atol=1e-12, rtol=0)


def test_so3_exp_batch_shape():
    omega = _rotvecs(6).reshape(2, 3, 3)
    rot = so3_exp(omega)
    assert rot.shape == (2, 3, 3, 3)
    # Each element is its own vector's rotation (scipy's).
    expected = torch.from_numpy(Rotation.from_rotvec(omega.reshape(6, 3).numpy()).as_matrix())
    torch.testing.assert_close(rot, expected.reshape(2, 3, 3, 3), atol=1e-12, rtol=0)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_so3_exp_small_angle_stable(dtype):
    omega = torch.tensor([[1e-8, -2e-8, 0.5e-8], [0.0, 0.0, 0.0]], dtype=dtype)
    rot = so3_exp(omega)
    assert torch.isfinite(rot).all()
    expected = torch.eye(3, dtype=dtype) + skew(omega)
    torch.testing.assert_close(rot, expected, atol=1e-12, rtol=0)
    torch.testing.assert_close(rot[1], torch.eye(3, dtype=dtype), atol=0, rtol=0)


def test_so3_exp_small_angle_gradient_finite():
    omega = torch.tensor([1e-8, 2e-8, -1e-8], dtype=torch.float64, requires_grad=True)
    so3_exp(omega).sum().backward()
    assert torch.isfinite(omega.grad).all()


def test_se3_exp_pure_translation():
    v = torch.tensor([[0.3, -1.2, 2.5]], dtype=torch.float64)
    xi = torch.cat([torch.zeros(1, 3, dtype=torch.float64), v], dim=-1)
    rot, trans = split_transform(se3_exp(xi))
    torch.testing.assert_close(rot[0], torch.eye(3, dtype=torch.float64))
    torch.testing.assert_close(trans, v)


def test_se3_exp_rotation_part_is_so3_exp():
    g = torch.Generator().manual_seed(4)
    xi = torch.randn(8, 6, generator=g, dtype=torch.float64)
    rot, _ = split_transform(se3_exp(xi))
    torch.testing.assert_close(rot, so3_exp(xi[:, :3]))


def test_se3_exp_matches_matrix_exponential():
    g = torch.Generator().manual_seed(5)
    xi = torch.randn(8, 6, generator=g, dtype=torch.float64)
    hat = torch.zeros(8, 4, 4, dtype=torch.float64)
    hat[:, :3, :3] = skew(xi[:, :3])
    hat[:, :3, 3] = xi[:, 3:]
    torch.testing.assert_close(se3_exp(xi), torch.linalg.matrix_exp(hat), atol=1e-12, rtol=0)


def test_se3_exp_of_negative_twist_is_inverse():
    g = torch.Generator().manual_seed(6)
    xi = torch.randn(16, 6, generator=g, dtype=torch.float64)
    xi[0] = 0
    xi[1, :3] = 1e-9
    product = se3_exp(xi) @ se3_exp(-xi)
    eye = torch.eye(4, dtype=torch.float64).expand_as(product)
    torch.testing.assert_close(product, eye, atol=1e-12, rtol=0)


def test_make_and_split_transform_round_trip():
    rot = so3_exp(_rotvecs(4, seed=7))
    trans = torch.arange(12, dtype=torch.float64).reshape(4, 3)
    t = make_transform(rot, trans)
    assert t.shape == (4, 4, 4)
    torch.testing.assert_close(
        t[:, 3], torch.tensor([0.0, 0, 0, 1], dtype=torch.float64).expand(4, 4)
    )
    r2, t2 = split_transform(t)
    torch.testing.assert_close(r2, rot)
    torch.testing.assert_close(t2, trans)


def test_invert_transform_round_trip():
    g = torch.Generator().manual_seed(8)
    transform = se3_exp(torch.randn(10, 6, generator=g, dtype=torch.float64) * 2)
    inv = invert_transform(transform)
    eye = torch.eye(4, dtype=torch.float64).expand_as(transform)
    torch.testing.assert_close(transform @ inv, eye, atol=1e-12, rtol=0)
    torch.testing.assert_close(inv @ transform, eye, atol=1e-12, rtol=0)
    torch.testing.assert_close(invert_transform(inv), transform, atol=1e-12, rtol=0)
    torch.testing.assert_close(inv, torch.linalg.inv(transform), atol=1e-12, rtol=0)


def test_transform_points_convention():
    g = torch.Generator().manual_seed(9)
    rot = so3_exp(_rotvecs(3, seed=9))
    trans = torch.randn(3, 3, generator=g, dtype=torch.float64)
    source = torch.randn(3, 20, 3, generator=g, dtype=torch.float64)
    transform = make_transform(rot, trans)
    got = transform_points(transform, source)
    # Row layout: template = source @ R.T + t; column layout: R @ p + t.
    torch.testing.assert_close(got, source @ rot.transpose(-1, -2) + trans[:, None, :])
    column = (rot[:, None] @ source[..., None])[..., 0] + trans[:, None, :]
    torch.testing.assert_close(got, column)
    # Homogeneous coordinates agree too.
    homog = torch.cat([source, torch.ones(3, 20, 1, dtype=torch.float64)], -1)
    torch.testing.assert_close(got, (homog @ transform.transpose(-1, -2))[..., :3])
    # And the inverse brings the points back.
    torch.testing.assert_close(transform_points(invert_transform(transform), got), source)


def test_transform_points_single_transform_many_points():
    transform = make_transform(torch.eye(3), torch.tensor([1.0, 2.0, 3.0]))
    points = torch.zeros(7, 3)
    assert torch.equal(
        transform_points(transform, points), torch.tensor([[1.0, 2.0, 3.0]]).expand(7, 3)
    )


def test_random_rotation_angles_within_range_and_cover_it():
    g = torch.Generator().manual_seed(10)
    rot = random_rotation(4000, 45.0, generator=g, dtype=torch.float64)
    assert rot.shape == (4000, 3, 3)
    eye = torch.eye(3, dtype=torch.float64).expand_as(rot)
    torch.testing.assert_close(rot @ rot.transpose(-1, -2), eye, atol=1e-12, rtol=0)
    deg = torch.rad2deg(rotation_angle(rot))
    assert deg.min() >= 0
    assert deg.max() <= 45.0 + 1e-6
    assert deg.min() < 1.0
    assert deg.max() > 44.0
    # Uniform in [0, 45]: every 9-degree bin holds about a fifth of the samples.
    counts = torch.histc(deg, bins=5, min=0, max=45)
    assert (counts > 0.15 * 4000).all() and (counts < 0.25 * 4000).all()


def test_random_rotation_seeded_and_dtype():
    a = random_rotation(5, 30.0, generator=torch.Generator().manual_seed(1))
    b = random_rotation(5, 30.0, generator=torch.Generator().manual_seed(1))
    c = random_rotation(5, 30.0, generator=torch.Generator().manual_seed(2))
    assert a.dtype == torch.float32
    assert torch.equal(a, b)
    assert not torch.equal(a, c)


def test_rotation_angle_matches_rotvec_norm():
    omega = _rotvecs(32, seed=11, max_angle=3.0)
    torch.testing.assert_close(
        rotation_angle(so3_exp(omega)), omega.norm(dim=-1), atol=1e-7, rtol=0
    )


def test_rotation_error_deg_of_known_rotation():
    r30 = torch.from_numpy(Rotation.from_euler("z", 30, degrees=True).as_matrix())
    eye = torch.eye(3, dtype=torch.float64)
    torch.testing.assert_close(
        rotation_error_deg(r30, eye), torch.tensor(30.0, dtype=torch.float64)
    )
    torch.testing.assert_close(
        rotation_error_deg(eye, r30), torch.tensor(30.0, dtype=torch.float64)
    )
    # Composition: error between R and R @ R30 is 30 degrees whatever R is.
    r = so3_exp(_rotvecs(4, seed=12))
    err = rotation_error_deg(r, r @ r30)
    torch.testing.assert_close(err, torch.full((4,), 30.0, dtype=torch.float64))
    assert rotation_error_deg(r, r).abs().max() < 1e-5


def test_rotation_error_near_180_degrees_is_finite():
    r = torch.from_numpy(Rotation.from_rotvec([0.0, 0.0, math.pi]).as_matrix())
    err = rotation_error_deg(r, torch.eye(3, dtype=torch.float64))
    assert np.isclose(float(err), 180.0, atol=1e-5)


def test_translation_error():
    a = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    b = torch.tensor([[3.0, 4.0, 0.0], [1.0, 1.0, 1.0]])
    torch.testing.assert_close(translation_error(a, b), torch.tensor([5.0, 0.0]))


def test_rotation_angle_is_accurate_for_tiny_angles():
    omega = torch.tensor([[1e-6, 0.0, 0.0], [0.0, 3e-7, 4e-7]])
    angle = rotation_angle(so3_exp(omega))  # float32
    torch.testing.assert_close(angle, omega.norm(dim=-1), rtol=1e-3, atol=0)


def test_rotation_angle_takes_numpy_and_torch_alike():
    omega = torch.tensor([[0.0, 0.0, 0.0], [1e-8, 0.0, 0.0], [0.0, 0.3, 0.4], [0.0, 0.0, 3.14159]])
    rotations = so3_exp(omega.double())
    from_torch = rotation_angle(rotations)
    from_numpy = rotation_angle(rotations.numpy())
    assert isinstance(from_numpy, np.ndarray)
    np.testing.assert_allclose(from_numpy, from_torch.numpy(), atol=1e-12)
    np.testing.assert_allclose(from_numpy, omega.norm(dim=-1).numpy(), atol=1e-9)
    assert from_numpy[1] == pytest.approx(1e-8, rel=1e-6)  # atan2 keeps tiny angles


def test_rotation_angle_deg_in_degrees():
    from masknet.geometry.se3 import rotation_angle_deg

    turn = so3_exp(torch.tensor([0.0, 0.0, np.pi / 2], dtype=torch.float64)).numpy()
    assert rotation_angle_deg(turn) == pytest.approx(90.0)
    assert float(rotation_angle_deg(torch.from_numpy(turn))) == pytest.approx(90.0)

"""Rigid transforms: the project's one SE(3) module.

Transform convention (used everywhere in masknet)
-------------------------------------------------
A rigid transform is a 4x4 homogeneous matrix ``T = [[R, t], [0, 1]]`` that maps
**source points into the template frame**::

    template ~= R @ source + t          (points as column vectors)
    template ~= source @ R.T + t        (points as rows, the layout used in code)

Pair generation stores the ground truth in this convention, and every
registration result returns it. Units are those of the point coordinates
(ModelNet40 shapes are scaled to unit radius). Angles are in radians unless a
name ends in ``_deg``.

Twists ``xi = (omega, v)`` in R^6 put the rotation part first, as PointNetLK does.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
import torch
from torch import Tensor

__all__ = [
    "skew",
    "so3_exp",
    "se3_exp",
    "make_transform",
    "quaternion_to_rotation",
    "split_transform",
    "invert_transform",
    "transform_points",
    "random_rotation",
    "rotation_angle",
    "rotation_angle_deg",
    "rotation_error_deg",
    "translation_error",
    "hypothesis_rotations",
]


def skew(v: Tensor) -> Tensor:
    """Cross-product matrices: (..., 3) -> (..., 3, 3), with ``skew(a) @ b == a x b``."""
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([o, -z, y, z, o, -x, -y, x, o], dim=-1).reshape(*v.shape[:-1], 3, 3)


def _exp_coefficients(theta: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """sin(t)/t, (1-cos t)/t^2 and (t - sin t)/t^3, with Taylor series near zero."""
    small = theta < 1e-4
    t = torch.where(small, torch.ones_like(theta), theta)
    t2 = t * t
    a = torch.where(small, 1 - theta**2 / 6, torch.sin(t) / t)
    b = torch.where(small, 0.5 - theta**2 / 24, (1 - torch.cos(t)) / t2)
    c = torch.where(small, 1 / 6 - theta**2 / 120, (t - torch.sin(t)) / (t2 * t))
    return a, b, c


def so3_exp(omega: Tensor) -> Tensor:
    """Rodrigues' formula: axis-angle vectors (..., 3) -> rotation matrices (..., 3, 3)."""
    theta = omega.norm(dim=-1)[..., None, None]
    a, b, _ = _exp_coefficients(theta)
    k = skew(omega)
    eye = torch.eye(3, dtype=omega.dtype, device=omega.device).expand_as(k)
    return eye + a * k + b * (k @ k)


def se3_exp(xi: Tensor) -> Tensor:
    """Exponential map of twists ``(omega, v)``: (..., 6) -> transforms (..., 4, 4)."""
    omega, v = xi[..., :3], xi[..., 3:]
    theta = omega.norm(dim=-1)[..., None, None]
    a, b, c = _exp_coefficients(theta)
    k = skew(omega)
    eye = torch.eye(3, dtype=xi.dtype, device=xi.device).expand_as(k)
    k2 = k @ k
    rot = eye + a * k + b * k2
    left_jacobian = eye + b * k + c * k2
    return make_transform(rot, (left_jacobian @ v[..., None])[..., 0])


def make_transform(rotation: Tensor, translation: Tensor) -> Tensor:
    """(..., 3, 3) and (..., 3) -> homogeneous (..., 4, 4)."""
    batch = rotation.shape[:-2]
    out = torch.zeros(*batch, 4, 4, dtype=rotation.dtype, device=rotation.device)
    out[..., :3, :3] = rotation
    out[..., :3, 3] = translation
    out[..., 3, 3] = 1
    return out


def quaternion_to_rotation(quaternion: Tensor) -> Tensor:
    """Rotation matrices (..., 3, 3) of quaternions (..., 4) ordered (w, x, y, z).

    The quaternion is normalised first, so any non-zero 4-vector is accepted (PCRNet
    regresses unnormalised ones); q and -q give the same rotation.
    """
    w, x, y, z = (quaternion / quaternion.norm(dim=-1, keepdim=True).clamp_min(1e-12)).unbind(-1)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return torch.stack([torch.stack(r, -1) for r in rows], -2)


def split_transform(transform: Tensor) -> tuple[Tensor, Tensor]:
    """(..., 4, 4) -> rotation (..., 3, 3), translation (..., 3)."""
    return transform[..., :3, :3], transform[..., :3, 3]


def invert_transform(transform: Tensor) -> Tensor:
    """Inverse of rigid transforms (..., 4, 4), using R^-1 = R^T."""
    rot, trans = split_transform(transform)
    rot_t = rot.transpose(-1, -2)
    return make_transform(rot_t, -(rot_t @ trans[..., None])[..., 0])


def transform_points(transform: Any, points: Any) -> Any:
    """Apply (..., 4, 4) transforms to row-vector points (..., N, 3) -> (..., N, 3).

    The one way to apply a transform: numpy arrays stay numpy (float64 where either is),
    tensors stay tensors (in the points' dtype)."""
    if isinstance(points, Tensor):
        transform = torch.as_tensor(transform, device=points.device).to(points.dtype)
    elif isinstance(transform, Tensor):  # numpy points stay numpy
        transform = transform.detach().cpu().numpy()
    rot, trans = split_transform(transform)
    return points @ rot.swapaxes(-1, -2) + trans[..., None, :]


def random_rotation(
    batch: int,
    max_angle_deg: float,
    generator: torch.Generator | None = None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """Rotations about uniformly random axes with angles uniform in [0, max_angle_deg].

    Returns (batch, 3, 3). This is the paper's protocol (not uniform on SO(3)).
    """
    axis = torch.randn(batch, 3, generator=generator, dtype=torch.float64)
    axis = axis / axis.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    angle = torch.rand(batch, 1, generator=generator, dtype=torch.float64)
    angle = angle * math.radians(max_angle_deg)
    return so3_exp(axis * angle).to(dtype)


def rotation_angle(rotation: Any) -> Any:
    """Geodesic angle in radians of rotation matrices (..., 3, 3) -> (...), numpy or torch.

    The one rotation angle of the package. atan2(sin, cos) stays accurate near 0 and pi,
    where arccos((tr - 1) / 2) loses about half the digits (a 1e-8 rad rotation would read
    as ~1e-4 rad in float32).
    """
    r = rotation
    trace = r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2]
    skew = (r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1])
    if isinstance(r, Tensor):
        return torch.atan2(torch.stack(skew, -1).norm(dim=-1) / 2, (trace - 1) / 2)
    sin = np.linalg.norm(np.stack(skew, -1), axis=-1) / 2
    return np.arctan2(sin, (trace - 1) / 2)


def rotation_angle_deg(rotation: Any) -> Any:
    """:func:`rotation_angle` in degrees: (..., 3, 3) -> (...), numpy or torch."""
    angle = rotation_angle(rotation)
    return torch.rad2deg(angle) if isinstance(angle, Tensor) else np.degrees(angle)


def rotation_error_deg(r_pred: Tensor, r_true: Tensor) -> Tensor:
    """Geodesic angle between rotations, in degrees: (..., 3, 3) x2 -> (...)."""
    return torch.rad2deg(rotation_angle(r_pred.transpose(-1, -2) @ r_true))


def translation_error(t_pred: Tensor, t_true: Tensor) -> Tensor:
    """Euclidean distance between translations (..., 3) x2 -> (...), in point units."""
    return (t_pred - t_true).norm(dim=-1)


@functools.cache
def hypothesis_rotations(count: int) -> np.ndarray:
    """(count, 3, 3) starting rotations: the 24 rotations of the cube, nearest the
    identity first, then seeded random rotations; read-only (computed once per count)."""
    from scipy.spatial.transform import Rotation

    cube = Rotation.create_group("O").as_matrix()
    cube = cube[np.argsort(np.round(rotation_angle(cube), 9), kind="stable")]
    out = (
        cube[:count]
        if count <= len(cube)
        else np.concatenate([cube, Rotation.random(count - len(cube), random_state=0).as_matrix()])
    )
    out.flags.writeable = False  # cached: shared by every caller
    return out

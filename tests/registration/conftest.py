"""Fixtures of the registration tests: ModelNet40 pairs with a known transform and overlap
mask, the shipped PointNetLK, and two helpers (a pose error and extent-keeping decoys)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest

from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs


class KnownPairs(NamedTuple):
    """template (B, N, 3), source (B, M, 3), float64; transform (B, 4, 4) the true
    source -> template; mask (B, N) bool the template points the source sees."""

    template: np.ndarray
    source: np.ndarray
    transform: np.ndarray
    mask: np.ndarray


@pytest.fixture(scope="module")
def known_pairs() -> KnownPairs:
    """Two 70% views of bundled ModelNet40 shapes (1,024 template points, 717 source
    points), turned by 2.4 and 0.76 degrees and moved by about 0.1 (seed 0). The source
    points are exactly the masked template points, moved."""
    shapes = load_modelnet40(bundled_sample_path()).points
    pairs = make_test_pairs(shapes, 2, PairConfig(max_angle_deg=10, max_translation=0.1), seed=0)
    return KnownPairs(
        pairs.template.double().numpy(),
        pairs.source.double().numpy(),
        pairs.transform.double().numpy(),
        pairs.mask.numpy(),
    )


@pytest.fixture(scope="module")
def shipped_pointnetlk():
    """The shipped PointNetLK weights, in eval mode."""
    from masknet.models import REGISTRATION_NETWORKS

    return REGISTRATION_NETWORKS["pointnetlk"].pretrained().eval()


def _pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation error in degrees (accurate near zero, unlike arccos of the trace) and
    translation error of (B, 4, 4) transforms."""
    estimate, truth = np.asarray(estimate, np.float64), np.asarray(truth, np.float64)
    diff = np.linalg.norm((estimate[:, :3, :3] - truth[:, :3, :3]).reshape(-1, 9), axis=1)
    degrees = np.degrees(2 * np.arcsin(np.minimum(diff / 8**0.5, 1)))
    return degrees, np.linalg.norm(estimate[:, :3, 3] - truth[:, :3, 3], axis=1)


@pytest.fixture(scope="session")
def pose_error():
    """``pose_error(estimate, truth) -> (degrees (B,), translation (B,))``."""
    return _pose_error


def _extent_decoys(template: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """A copy of template (B, N, 3) whose masked-out points (``mask`` False) are pulled
    halfway to the bounding-box centre, all but those that set the box or the radius: the
    cloud changes where the mask rejects it, yet keeps its bounding box and its radius
    (:func:`masknet.geometry.clouds.unit_radius`), the scale the back-ends derive from
    the whole template."""
    out = np.array(template, dtype=np.float64, copy=True)
    for b in range(len(out)):
        points = template[b]
        mid = (points.max(0) + points.min(0)) / 2
        fixed = {*points.argmin(0).tolist(), *points.argmax(0).tolist()}
        fixed.add(int(np.linalg.norm(points - mid, axis=1).argmax()))
        move = np.array([i for i in np.flatnonzero(~mask[b]) if i not in fixed])
        out[b, move] = 0.5 * points[move] + 0.5 * mid
    return out


@pytest.fixture(scope="session")
def extent_decoys():
    """``extent_decoys(template (B, N, 3), mask (B, N)) -> template`` with its masked-out
    points moved, its bounding box and radius kept."""
    return _extent_decoys

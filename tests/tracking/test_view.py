"""masknet.tracking.view: the scene's plane beyond the object's reach, and the template's
side a sensor sees."""

from __future__ import annotations

import numpy as np

from masknet.tracking.view import background_plane, visible_side


def _ball(rng: np.random.Generator, count: int) -> np.ndarray:
    """``count`` points on the unit sphere about (0, 0, 1.2): an object above z = 0."""
    v = rng.standard_normal((count, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True) + [0.0, 0.0, 1.2]


def test_the_floor_beyond_the_reach_is_dropped_under_the_object_too():
    rng = np.random.default_rng(0)
    floor = np.c_[rng.uniform(-2, 2, (4000, 2)), rng.normal(0, 0.003, 4000)]
    points = np.vstack([floor, _ball(rng, 800)])
    plane = background_plane(points, np.array([0.0, 0.0, 1.2]), 1.1, 0.02, tries=100, min_points=30)
    assert plane[:4000].all()  # the floor, also the patch under the ball
    assert plane[4000:].mean() < 0.02  # the ball keeps its points (bar a sliver at its foot)


def test_a_flat_face_within_the_reach_is_never_the_scenes():
    rng = np.random.default_rng(1)
    face = np.c_[rng.uniform(-0.7, 0.7, (2000, 2)), np.zeros(2000)]  # a screen, all near
    clutter = rng.uniform(-3, 3, (20, 3))  # too few beyond the reach to make a plane
    points = np.vstack([face, clutter])
    plane = background_plane(points, np.zeros(3), 1.1, 0.02, tries=100, min_points=30)
    assert not plane.any()


def test_the_side_facing_the_sensor_is_seen():
    rng = np.random.default_rng(2)
    sphere = _ball(rng, 2000) - [0.0, 0.0, 1.2]
    transform = np.eye(4)
    transform[:3, 3] = [0.0, 0.0, -5.0]  # frame -> template: the sphere 5 along +z
    seen = visible_side(sphere, transform, np.zeros(3))  # the sensor at the frame's origin
    assert 0.3 < seen.mean() < 0.7
    assert (sphere[seen, 2] < 0).all()  # the half facing the sensor (towards -z)

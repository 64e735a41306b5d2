"""What of a tracked frame is the object's, and what of the template the camera sees.

A tracked frame is cut to a ball around the predicted object (:func:`points_near`), and that ball holds more than the object: the floor it stands on
(and a wall behind it) crosses the whole ball. Those points pull ICP towards the floor and
count against the pose in the verdict's overlap fit (a floor point under a wing lies within
the overlap band of the template but not on it), so a right pose read ``likely wrong``.
Two things set them apart here:

* :func:`background_plane`: the plane that most points *beyond the object's reach* lie on
  (the object cannot put a point there, so a plane that holds many of them is the scene's,
  not the object's). Its points are dropped everywhere in the ball, under the object too.
  A flat face of the object itself (a monitor's screen) lies within its reach and is never
  chosen.
* :func:`visible_side`: the template points the camera sees at a pose (hidden point
  removal from the viewpoint): a depth frame holds one side of the object, and the
  template's far side is no evidence against a pose.
"""

from __future__ import annotations

import numpy as np

from masknet.geometry.normals import least_spread_axis

__all__ = ["background_plane", "points_near", "turned", "visible_side", "without_planes"]

SCORED_POINTS = 2048  # a RANSAC plane is scored on at most this many points beyond the reach


def background_plane(
    points: np.ndarray,
    centre: np.ndarray,
    reach: float,
    band: float,
    *,
    tries: int,
    min_points: int,
    seed: int = 0,
) -> np.ndarray:
    """(P,) bool: the points of ``points`` (P, 3) on the scene's plane, or none.

    The plane is the one (RANSAC, ``tries`` samples of three points, seeded) that the most
    points farther than ``reach`` from ``centre`` (3,) lie within ``band`` of (input units);
    it is refined by least squares on those points, and every point of ``points`` within
    ``band`` of it is marked, whatever its distance from ``centre``. No point is marked
    where fewer than ``min_points`` points beyond the reach lie on the best plane.
    """
    points = np.asarray(points, dtype=np.float64)
    none = np.zeros(len(points), dtype=bool)
    beyond = points[np.linalg.norm(points - centre, axis=1) > reach]
    if len(beyond) < max(min_points, 3):
        return none
    rng = np.random.default_rng(seed)
    scored = beyond[rng.permutation(len(beyond))[:SCORED_POINTS]]
    corners = beyond[rng.integers(0, len(beyond), (tries, 3))]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    lengths = np.linalg.norm(normals, axis=1)
    sound = lengths > 1e-12 * max(reach, 1e-300) ** 2
    if not sound.any():
        return none
    normals = normals[sound] / lengths[sound, None]
    offsets = np.einsum("ij,ij->i", normals, corners[sound, 0])
    on = np.abs(scored @ normals.T - offsets) <= band  # (scored, tries)
    best = int(np.argmax(on.sum(0)))
    # The count beyond the reach, on the whole set: the scored subset may be a sample.
    on_best = np.abs(beyond @ normals[best] - offsets[best]) <= band
    if on_best.sum() < min_points:
        return none
    support = beyond[on_best]
    middle = support.mean(0)
    normal = least_spread_axis(support)  # the least-squares plane's, through ``middle``
    return np.abs((points - middle) @ normal) <= band


def without_planes(
    points: np.ndarray,
    centre: np.ndarray,
    reach: float,
    band: float,
    planes: int,
    tries: int,
    min_points: int,
    seed: int = 0,
) -> np.ndarray:
    """``points`` (P, 3) less those on up to ``planes`` scene planes, found one after the
    other (:func:`background_plane`, its arguments): (K, 3)."""
    for _ in range(planes):
        plane = background_plane(
            points, centre, reach, band, tries=tries, min_points=min_points, seed=seed
        )
        if not plane.any():
            break
        points = points[~plane]
    return points


def visible_side(template: np.ndarray, transform: np.ndarray, viewpoint: np.ndarray) -> np.ndarray:
    """(N,) bool: the points of ``template`` (N, 3) seen from ``viewpoint`` (3,), frame
    coordinates, with the object at ``transform`` (4, 4, frame -> template): hidden point
    removal (:func:`masknet.data.views.hidden_point_removal`) from the viewpoint carried
    into the template's frame."""
    from masknet.data.views import hidden_point_removal

    eye = transform[:3, :3] @ np.asarray(viewpoint, dtype=np.float64) + transform[:3, 3]
    return hidden_point_removal(template, eye)


def points_near(
    points: np.ndarray, transform: np.ndarray, centre: np.ndarray, reach: float
) -> np.ndarray:
    """The frame points (K, 3) of ``points`` (P, 3) within ``reach`` (input units) of the
    template point ``centre`` (3,) placed in the frame by ``transform`` (4, 4), frame ->
    template: the object's surroundings, where its verdict is asked."""
    placed = np.linalg.solve(transform, np.append(centre, 1.0))[:3]
    return points[np.linalg.norm(points - placed, axis=1) <= reach]


def turned(
    transform: np.ndarray, centre: np.ndarray, angles: tuple[float, ...]
) -> list[np.ndarray]:
    """``transform`` (4, 4, frame -> template) followed by turns of the template about
    ``centre`` (3,): itself, then each nonzero angle of ``angles`` (degrees) about the x, y
    and z axes, both ways (1 + 6 per angle transforms)."""
    from scipy.spatial.transform import Rotation

    starts = [transform]
    for angle in (a for a in angles if a != 0):
        for axis in np.concatenate([np.eye(3), -np.eye(3)]):
            turn = np.eye(4)
            turn[:3, :3] = Rotation.from_rotvec(np.deg2rad(angle) * axis).as_matrix()
            turn[:3, 3] = centre - turn[:3, :3] @ centre
            starts.append(turn @ transform)
    return starts

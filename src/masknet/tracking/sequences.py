"""Synthetic tracking sequences with known truth: a ModelNet40 object moving on a floor.

Each frame is what one depth camera sees of a small scene, in the camera's coordinates
(x right, y down, z forward, the camera at the origin): a floor plane, a few other
ModelNet40 shapes standing on it as clutter, and the tracked object, which turns about
the vertical and slides along the floor a little every frame. Every frame samples the
surfaces anew (the object's points between neighbouring points of its shape, so that no
frame repeats the template's points), keeps only what the camera sees
(:func:`masknet.data.views.hidden_point_removal`) and adds Gaussian noise, as a sensor
does. Partway through, a wall stands between the camera and the object for a few frames
(the object is hidden), and later the object jumps: it turns by tens of degrees and
shifts by a fifth of its radius in one frame.

Lengths are in the object's radius (ModelNet40's shapes have radius 1); scenes hold
about 5,000-8,000 points. The truth is in :func:`masknet.register`'s convention: a
(4, 4) transform that maps frame points into the template frame
(:mod:`masknet.geometry.se3`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from masknet.data.views import hidden_point_removal
from masknet.geometry.clouds import unit_radius

__all__ = ["Sequence", "SequenceConfig", "make_sequence", "sequences_from_shapes"]

# Clutter stands behind the object's path (seen from the camera), at least 2 radii from
# it, so that it hides nothing of the object; (x, y) on the floor.
CLUTTER_SPOTS = ((-2.6, 2.6), (0.6, 3.2), (3.0, 2.2), (-3.6, -0.5))
CAMERA = np.array([0.0, -6.0, 3.5])  # world position, looking at LOOK_AT
LOOK_AT = np.array([0.0, 0.0, 0.5])
FLOOR = ((-5.0, 5.0), (-3.0, 5.0))  # x and y extent of the floor, in radii
WALL_Y = -2.0  # the occluding wall's plane (between the camera and the path)
NEIGHBOURS = 6  # a frame's surface point lies between a shape point and one of these


@dataclass(frozen=True)
class SequenceConfig:
    """How a sequence moves. Angles in degrees, lengths in object radii.

    frames: frames in the sequence.
    step_deg, step_shift: the largest turn and slide per frame (the motion eases between
        a quarter of them and all of them).
    occlusion_at, occlusion_frames: the first frame the wall hides the object (a share
        of ``frames``), and for how many frames; 0 frames: no wall.
    jump_at, jump_deg, jump_shift: the frame of the sudden jump (a share of ``frames``),
        its turn and its shift; 0 degrees and shift: no jump.
    floor_points, clutter: points on the floor per frame, other shapes in the scene.
    noise_sigma: the sensor's Gaussian noise (clipped at 3 sigma).
    """

    frames: int = 100
    step_deg: float = 3.0
    step_shift: float = 0.03
    occlusion_at: float = 0.3
    occlusion_frames: int = 8
    jump_at: float = 0.65
    jump_deg: float = 30.0
    jump_shift: float = 0.2
    floor_points: int = 4000
    clutter: int = 3
    noise_sigma: float = 0.005

    def __post_init__(self) -> None:
        if self.frames < 2:
            raise ValueError(f"frames must be at least 2, got {self.frames}")
        if not 0 <= self.clutter <= len(CLUTTER_SPOTS):
            raise ValueError(f"clutter must be in [0, {len(CLUTTER_SPOTS)}], got {self.clutter}")

    @property
    def occluded_frames(self) -> range:
        """The frames the wall hides the object in."""
        first = round(self.occlusion_at * self.frames)
        return range(first, min(self.frames, first + self.occlusion_frames))

    @property
    def jump_frame(self) -> int | None:
        """The frame of the jump (the first frame at the new pose), None without one."""
        if self.jump_deg == 0 and self.jump_shift == 0:
            return None
        return min(self.frames - 1, max(1, round(self.jump_at * self.frames)))


class Sequence(NamedTuple):
    """A tracking sequence with its truth.

    name: the object's ModelNet40 name. template: (N, 3) float64, the object's shape in
    its own frame. frames: F clouds (P_f, 3) float64 in camera coordinates. truth:
    (F, 4, 4) float64, each frame -> template (``template ~ frame_points @ R.T + t`` on the
    object's points). occluded: (F,) bool, the frames the object is hidden in. jump: the
    frame of the jump, or None. viewpoint: (3,) the camera in frame coordinates (the
    origin). radius: the object's radius (:func:`~masknet.geometry.clouds.unit_radius`).
    """

    name: str
    template: np.ndarray
    frames: list[np.ndarray]
    truth: np.ndarray
    occluded: np.ndarray
    jump: int | None
    viewpoint: np.ndarray
    radius: float


def _camera_from_world() -> np.ndarray:
    """(4, 4): world -> camera coordinates (x right, y down, z forward)."""
    forward = (LOOK_AT - CAMERA) / np.linalg.norm(LOOK_AT - CAMERA)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    rotation = np.stack([right, down, forward])
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rotation, -rotation @ CAMERA
    return out


def _pose(yaw_deg: float, position: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    out[:3, 3] = position
    return out


def _resampled(shape: np.ndarray, neighbours: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A fresh sampling of a shape's surface (N, 3): each point moved part of the way
    towards one of its nearest neighbours, so that no point repeats the shape's own."""
    pick = rng.integers(1, neighbours.shape[1], len(shape))
    other = shape[neighbours[np.arange(len(shape)), pick]]
    return shape + rng.uniform(0, 0.5, (len(shape), 1)) * (other - shape)


def _world_poses(config: SequenceConfig, rng: np.random.Generator, lift: float) -> np.ndarray:
    """(F, 4, 4): the object's frame -> world, standing on the floor (``lift`` raises its
    lowest point to it), easing along the path, with the jump."""
    k = np.arange(config.frames)
    phase = rng.uniform(0, 2 * np.pi, 2)
    ease = lambda p: 0.25 + 0.75 * (0.5 + 0.5 * np.sin(2 * np.pi * k / 40 + p))  # noqa: E731
    turn = config.step_deg * ease(phase[0]) * rng.choice([-1, 1])
    slide = config.step_shift * ease(phase[1])
    heading = rng.uniform(-0.3, 0.3)  # mostly across the camera's view
    yaw = rng.uniform(0, 360) + np.concatenate([[0], np.cumsum(turn[1:])])
    travel = np.concatenate([[0], np.cumsum(slide[1:])])
    start = -travel[-1] / 2  # the path is centred in front of the camera
    xy = np.array([np.cos(heading), np.sin(heading)]) * (start + travel)[:, None]
    jump = config.jump_frame
    if jump is not None:
        yaw[jump:] += config.jump_deg * rng.choice([-1, 1])
        side = np.array([-np.sin(heading), np.cos(heading)]) * rng.choice([-1, 1])
        xy[jump:] += config.jump_shift * side
    return np.stack([_pose(a, np.array([x, y, lift])) for a, (x, y) in zip(yaw, xy, strict=True)])


def _behind_wall(points: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(P,) bool: world points whose line of sight crosses the wall, a 3 x 3 radii panel
    in the plane y = WALL_Y, on the line from the camera to ``centre``."""
    s_centre = (WALL_Y - CAMERA[1]) / (centre[1] - CAMERA[1])
    middle = CAMERA + s_centre * (centre - CAMERA)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (WALL_Y - CAMERA[1]) / (points[:, 1] - CAMERA[1])
    hit = CAMERA + s[:, None] * (points - CAMERA)
    inside = (np.abs(hit[:, 0] - middle[0]) < 1.5) & (np.abs(hit[:, 2] - middle[2]) < 1.5)
    return (s > 0) & (s < 1) & inside


def _wall_points(centre: np.ndarray, rng: np.random.Generator, count: int = 1500) -> np.ndarray:
    s_centre = (WALL_Y - CAMERA[1]) / (centre[1] - CAMERA[1])
    middle = CAMERA + s_centre * (centre - CAMERA)
    x, z = rng.uniform(-1.45, 1.45, (2, count))
    return np.stack([middle[0] + x, np.full(count, WALL_Y), middle[2] + z], 1)


def make_sequence(
    shape: np.ndarray,
    clutter: list[np.ndarray],
    config: SequenceConfig | None = None,
    seed: int = 0,
    name: str = "",
) -> Sequence:
    """One sequence of ``shape`` (N, 3), a unit-radius ModelNet40 shape, among the
    ``clutter`` shapes (each (K, 3); the first ``config.clutter`` are used), seeded.

    Returns:
        :class:`Sequence`; the template is ``shape`` as float64, in its own frame.
    """
    config = config or SequenceConfig()
    rng = np.random.default_rng(seed)
    template = np.asarray(shape, dtype=np.float64)
    poses = _world_poses(config, rng, lift=-float(template[:, 2].min()))
    props = []  # (shape, its neighbours, its pose in the world), standing on the floor
    for (x, y), other in zip(CLUTTER_SPOTS, clutter[: config.clutter], strict=False):
        other = np.asarray(other, dtype=np.float64) * rng.uniform(0.8, 1.2)
        pose = _pose(rng.uniform(0, 360), np.array([x, y, -other[:, 2].min()]))
        props.append((other, _neighbours(other), pose))
    own = _neighbours(template)
    camera = _camera_from_world()
    occluded = np.zeros(config.frames, dtype=bool)
    occluded[list(config.occluded_frames)] = True
    frames, truth = [], []
    for k in range(config.frames):
        parts = [_floor(config.floor_points, rng)]
        parts += [_moved(pose, _resampled(s, nb, rng)) for s, nb, pose in props]
        parts.append(_moved(poses[k], _resampled(template, own, rng)))
        world = np.concatenate(parts)
        if occluded[k]:
            world = world[~_behind_wall(world, poses[k][:3, 3])]
            world = np.concatenate([world, _wall_points(poses[k][:3, 3], rng)])
        world = world[hidden_point_removal(world, CAMERA)]
        sigma = config.noise_sigma
        noise = (rng.standard_normal(world.shape) * sigma).clip(-3 * sigma, 3 * sigma)
        frames.append(_moved(camera, world + noise))
        truth.append(np.linalg.inv(camera @ poses[k]))  # frame -> object frame
    return Sequence(
        name,
        template,
        frames,
        np.stack(truth),
        occluded,
        config.jump_frame,
        np.zeros(3),
        float(unit_radius(template)),
    )


def sequences_from_shapes(
    points: np.ndarray,
    names: list[str],
    objects: list[int],
    config: SequenceConfig | None = None,
    seed: int = 0,
) -> list[Sequence]:
    """One sequence per index of ``objects`` into ``points`` (S, N, 3) (ModelNet40 test
    shapes, ``names`` (S,)), each with the next shapes of the set (not among
    ``objects``) as clutter, seeded by ``seed`` and its position."""
    config = config or SequenceConfig()
    others = [i for i in range(len(points)) if i not in set(objects)]
    out = []
    for n, index in enumerate(objects):
        pick = [others[(n * config.clutter + j) % len(others)] for j in range(config.clutter)]
        out.append(
            make_sequence(
                points[index], [points[j] for j in pick], config, seed + n, str(names[index])
            )
        )
    return out


def _neighbours(shape: np.ndarray) -> np.ndarray:
    from masknet.geometry.knn import cloud_tree

    return cloud_tree(shape).query(shape, k=NEIGHBOURS)[1].astype(np.int64)


def _moved(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ pose[:3, :3].T + pose[:3, 3]


def _floor(count: int, rng: np.random.Generator) -> np.ndarray:
    (x0, x1), (y0, y1) = FLOOR
    return np.stack([rng.uniform(x0, x1, count), rng.uniform(y0, y1, count), np.zeros(count)], 1)

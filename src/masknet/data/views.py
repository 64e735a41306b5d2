"""Sensor-like pairs: a view of a cloud seen from a viewpoint, sampled apart from its template.

The paper's pairs (:mod:`masknet.data.pairs`) copy the source's points from the template,
so every source point has an exact twin. A real re-scan does not: it is sampled anew,
sees only the surface that faces the sensor, and is noisy. :func:`make_view_pair` makes
such a pair from any dense cloud (a ModelNet40 shape or a crop of a real scan,
:mod:`masknet.data.scans`):

1. the cloud's points are split at random into two disjoint halves; the template is
   drawn from one, the source from the other, so that no point is shared;
2. a viewpoint is drawn on a sphere of radius ``view_distance`` (in cloud radii) around
   the cloud; the *view* is the ``keep_ratio`` fraction of the cloud's points that are
   visible from it (hidden-point removal, Katz et al. 2007) and nearest to it (occluded
   points only fill in when too few are visible);
3. the source is ``keep_ratio * N`` points of the second half inside the view, drawn
   with a density that falls off with the distance to the viewpoint, as a sensor's does;
4. the ground-truth mask is geometric: a template point is an inlier when it lies on
   the viewed surface, the part of the cloud the source was sampled from;
5. the source is moved (rotation about a random axis, uniform angle, uniform
   translation) and gets Gaussian noise in proportion to the cloud's radius.

No label is needed beyond the cloud itself: this is the label-free training on real
scans that the paper names as future work. Distances are in units of the cloud's radius:
:func:`normalize_cloud` brings any cloud to unit radius first.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
import torch
from scipy.spatial import ConvexHull, QhullError
from scipy.spatial.transform import Rotation

from masknet.data.pairs import Pairs
from masknet.geometry.clouds import unit_radius

__all__ = [
    "ViewConfig",
    "hidden_point_removal",
    "make_view_pair",
    "make_view_pairs",
    "normalize_cloud",
]


@dataclass(frozen=True)
class ViewConfig:
    """How a sensor-like pair is made. Distances are in cloud radii (clouds of radius 1).

    template_points: N, template points per pair (the cloud needs at least 2N points
        when ``independent``).
    keep_ratio: the source covers this fraction of the cloud and has ``keep_ratio * N``
        points, as the paper's 30%-missing protocol.
    max_angle_deg, max_translation: the source's motion, as in :class:`PairConfig`.
    noise_sigma: Gaussian noise on the source, as a fraction of the radius (0.002 is
        0.2% of the radius); clipped at 3 sigma.
    random_noise: each pair draws its sigma uniformly from [0, ``noise_sigma``] (training).
    view_distance: (min, max) distance of the viewpoint from the centre, uniform.
    visibility: remove points hidden from the viewpoint (hidden-point removal).
    falloff: source density falls off as distance^-falloff from the viewpoint (0: uniform).
    independent: sample template and source from disjoint halves of the cloud.
    """

    template_points: int = 512
    keep_ratio: float = 0.7
    max_angle_deg: float = 45.0
    max_translation: float = 1.0
    noise_sigma: float = 0.002
    random_noise: bool = False
    view_distance: tuple[float, float] = (2.0, 6.0)
    visibility: bool = True
    falloff: float = 2.0
    independent: bool = True

    def __post_init__(self) -> None:
        if self.template_points < 16:
            raise ValueError(f"template_points must be at least 16, got {self.template_points}")
        if not 0 < self.keep_ratio <= 1:
            raise ValueError(f"keep_ratio must be in (0, 1], got {self.keep_ratio}")
        lo, hi = self.view_distance
        if not 1 < lo <= hi:
            raise ValueError(f"view_distance must be (min, max) with 1 < min <= max, got {lo, hi}")
        if self.noise_sigma < 0:
            raise ValueError(f"noise_sigma must be >= 0, got {self.noise_sigma}")

    @property
    def source_points(self) -> int:
        """M, source points per pair."""
        return max(3, round(self.keep_ratio * self.template_points))

    @property
    def min_cloud_points(self) -> int:
        """The fewest cloud points a pair can be cut from."""
        return 2 * self.template_points if self.independent else self.template_points

    def to_dict(self) -> dict:
        return asdict(self)


def normalize_cloud(points: np.ndarray) -> np.ndarray:
    """(P, 3) -> (P, 3) float32, centred on its bounding-box centre, largest radius 1.

    The same normalisation as ModelNet40's shapes and MaskNet's ``normalize=True``.
    """
    points = np.asarray(points, dtype=np.float64)
    mid = (points.max(0) + points.min(0)) / 2
    return ((points - mid) / unit_radius(points)).astype(np.float32)


def hidden_point_removal(points: np.ndarray, viewpoint: np.ndarray) -> np.ndarray:
    """(P,) bool: the points visible from ``viewpoint`` (3,) (Katz, Tal and Basri, 2007).

    Spherical flipping about the viewpoint, then the convex hull: the points on the
    hull are the visible ones. Degenerate (flat or tiny) inputs see everything.
    """
    rel = points - viewpoint
    norm = np.linalg.norm(rel, axis=1, keepdims=True).clip(1e-12)
    radius = norm.max() * 100.0
    flipped = rel + 2 * (radius - norm) * rel / norm
    visible = np.zeros(len(points), dtype=bool)
    try:
        hull = ConvexHull(np.vstack([flipped, np.zeros((1, 3))]))
    except QhullError:
        visible[:] = True
        return visible
    vertices = hull.vertices[hull.vertices < len(points)]
    visible[vertices] = True
    return visible


def _random_direction(rng: np.random.Generator) -> np.ndarray:
    v = rng.standard_normal(3)
    return v / max(np.linalg.norm(v), 1e-12)


def make_view_pair(
    cloud: np.ndarray, config: ViewConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One sensor-like pair from a unit-radius cloud (P, 3), P >= ``config.min_cloud_points``.

    A cloud of more than ``4 N`` points is first subsampled to ``4 N`` at random: the
    cloud's extent, not its size, sets the scale of a pair.

    Returns:
        template (N, 3) float32, source (M, 3) float32 (moved, noisy), mask (N,) bool
        (template points on the viewed surface), transform (4, 4) float32 mapping
        source points into the template frame (``template ~ source @ R.T + t``).
    """
    n, m = config.template_points, config.source_points
    if len(cloud) < config.min_cloud_points:
        raise ValueError(
            f"a view pair needs {config.min_cloud_points} cloud points, got {len(cloud)}"
        )
    cloud = cloud[rng.permutation(len(cloud))[: 4 * n]]
    p = len(cloud)
    # The order is random, so the first n points are a random template and the second
    # half a disjoint pool for the source.
    pool = np.arange(p // 2, p) if config.independent else np.arange(p)

    lo, hi = config.view_distance
    viewpoint = _random_direction(rng) * rng.uniform(lo, hi)
    distance = np.linalg.norm(cloud - viewpoint, axis=1)
    hidden = ~hidden_point_removal(cloud, viewpoint) if config.visibility else np.zeros(p, bool)
    # Visible points first, nearest first; occluded ones only fill a view that is too small.
    ranked = np.lexsort((distance, hidden))
    in_view = np.zeros(p, dtype=bool)
    in_view[ranked[: max(m, round(config.keep_ratio * p))]] = True

    candidates = pool[in_view[pool]]
    weights = (distance[candidates] / distance[candidates].min()) ** -config.falloff
    replace = len(candidates) < m  # a thin view: a few source points repeat
    source = cloud[rng.choice(candidates, m, replace=replace, p=weights / weights.sum())]
    source = source.astype(np.float64)
    sigma = rng.uniform(0, config.noise_sigma) if config.random_noise else config.noise_sigma
    if sigma > 0:
        source += (rng.standard_normal(source.shape) * sigma).clip(-3 * sigma, 3 * sigma)

    # The source's motion: a rotation about a uniform axis by a uniform angle, as
    # geometry.random_rotation, and a uniform translation.
    angle = np.deg2rad(rng.uniform(0, config.max_angle_deg))
    rotation = Rotation.from_rotvec(_random_direction(rng) * angle).as_matrix()
    translation = rng.uniform(-1, 1, 3) * config.max_translation
    source = source @ rotation.T + translation  # template frame -> source frame
    transform = np.eye(4)
    transform[:3, :3], transform[:3, 3] = rotation.T, -rotation.T @ translation
    return (
        cloud[:n].astype(np.float32),
        source.astype(np.float32),
        in_view[:n],
        transform.astype(np.float32),
    )


def make_view_pairs(
    clouds: Sequence[np.ndarray], config: ViewConfig, rng: np.random.Generator
) -> Pairs:
    """A batch of :class:`Pairs`, one per unit-radius cloud (each (P_i, 3)).

    ``source_mask`` is all True: a view has no outliers.
    """
    parts = [make_view_pair(cloud, config, rng) for cloud in clouds]
    template, source, mask, transform = (np.stack(x) for x in zip(*parts, strict=True))
    return Pairs(
        torch.from_numpy(template),
        torch.from_numpy(source),
        torch.from_numpy(mask),
        torch.from_numpy(transform),
        torch.ones(source.shape[:2], dtype=torch.bool),
    )

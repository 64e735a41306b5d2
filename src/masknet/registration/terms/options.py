"""Typed options of :func:`masknet.register`, one small immutable object per method, in the
style of Open3D's ``ICPConvergenceCriteria``. Each checks its values when it is made:

    >>> register(template, source, options=ICPCriteria(max_iterations=30))
    >>> register(template, source, method="robust", options=RobustOptions(hypotheses=12))

Keywords are the same thing spelled inline: ``register(template, source, method="icp",
max_iterations=30)`` builds ``ICPCriteria(max_iterations=30)``. Giving the object and one
of its keywords is an error.

One name per idea, as Open3D names it: ``max_correspondence_distance`` is the pair cut-off
(in the clouds' units) everywhere, ``relative_rmse`` the stopping rule, ``max_iterations``
the updates within one round (rounds are :func:`register`'s ``iterations``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from masknet.errors import MaskNetError

__all__ = [
    "FGROptions",
    "ICPCriteria",
    "NetworkOptions",
    "Open3DICPOptions",
    "PointNetLKOptions",
    "RANSACOptions",
    "RobustOptions",
    "SceneSearch",
    "as_dict",
    "inlier_cutoff",
]

# The pair cut-off when none is given, in template point spacings (the median distance of
# a template point to its nearest neighbour): unit-free, and where right and wrong results
# fit most differently (docs/RESULTS.md, "Did a registration work?",
# scripts/fit_calibration.py); at 3 spacings wrong results fit as well as right ones.
DEFAULT_SPACINGS = 1.5


def inlier_cutoff(spacing: float) -> float:
    """The inlier cut-off of a cloud whose point spacing is ``spacing``
    (:func:`masknet.geometry.clouds.median_spacing`), in the cloud's units:
    ``DEFAULT_SPACINGS`` spacings. Every default cut-off of a fit, of ICP's pairs and of
    a covered point is this one; the caller measures the spacing (of which cloud, on how
    many points)."""
    return DEFAULT_SPACINGS * spacing


def as_dict(options: Any) -> dict[str, Any]:
    """An options object's fields by name (shallow: a ``network`` stays the same object)."""
    return {f.name: getattr(options, f.name) for f in dataclasses.fields(options)}


def _integer(name: str, value: Any, low: int) -> None:
    if isinstance(value, bool | np.bool_) or not isinstance(value, int | np.integer) or value < low:
        raise MaskNetError(f"{name} must be an integer >= {low}, got {value!r}")


def _positive(name: str, value: Any, allow_none: bool = True) -> None:
    if value is None and allow_none:
        return
    if not _number(value) or not (np.isfinite(value) and value > 0):
        raise MaskNetError(f"{name} must be a positive number, got {value!r}")


def _non_negative(name: str, value: Any) -> None:
    if not _number(value) or not value >= 0:
        raise MaskNetError(f"{name} must be a number >= 0, got {value!r}")


def _number(value: Any) -> bool:
    """A real number (numpy scalars too), not a bool."""
    return not isinstance(value, bool | np.bool_) and isinstance(value, int | float | np.number)


@dataclass(frozen=True)
class ICPCriteria:
    """Mask-ICP's rule within one round (``method="icp"``).

    max_iterations: updates per round (0 evaluates the start).
    relative_rmse: stop once the inlier RMSE changes by at most this fraction of itself
        (relative, unlike Open3D's absolute change, so that the stop is unit-free).
    max_correspondence_distance: pairs farther apart (in the clouds' units) are not used;
        None keeps every pair.
    """

    max_iterations: int = 10
    relative_rmse: float = 5e-7
    max_correspondence_distance: float | None = None

    def __post_init__(self) -> None:
        _integer("max_iterations", self.max_iterations, 0)
        _non_negative("relative_rmse", self.relative_rmse)
        _positive("max_correspondence_distance", self.max_correspondence_distance)


@dataclass(frozen=True)
class Open3DICPOptions:
    """Open3D's point-to-point ICP (``method="open3d-icp"``), with Open3D's criteria:
    ``relative_fitness`` and ``relative_rmse`` are Open3D's absolute changes."""

    max_iterations: int = 10
    max_correspondence_distance: float | None = None
    relative_fitness: float = 1e-6
    relative_rmse: float = 1e-6

    def __post_init__(self) -> None:
        _integer("max_iterations", self.max_iterations, 0)
        _positive("max_correspondence_distance", self.max_correspondence_distance)
        _non_negative("relative_fitness", self.relative_fitness)
        _non_negative("relative_rmse", self.relative_rmse)


@dataclass(frozen=True)
class NetworkOptions:
    """A learned registration network (DCP, PRNet, PCRNet, RPM-Net).

    max_iterations: passes of the network per round; None: its paper's (DCP 1, PRNet 3,
        PCRNet 8, RPM-Net 5, from the method table).
    network: a model of :data:`masknet.models.REGISTRATION_NETWORKS`; None: the shipped
        weights.
    """

    max_iterations: int | None = None
    network: Any = None

    def __post_init__(self) -> None:
        if self.max_iterations is not None:
            _integer("max_iterations", self.max_iterations, 1)


@dataclass(frozen=True)
class PointNetLKOptions(NetworkOptions):
    """PointNetLK: as :class:`NetworkOptions`, and ``tolerance``: a pair stops once its
    update's twist (rotation in radians, translation in template radii) has a norm
    below this."""

    tolerance: float = 1e-5

    def __post_init__(self) -> None:
        super().__post_init__()
        _non_negative("tolerance", self.tolerance)


@dataclass(frozen=True)
class RANSACOptions:
    """Open3D's RANSAC on FPFH features (``method="open3d-ransac"``).

    voxel_size: feature scale as a fraction of the template's radius
    (:func:`~masknet.geometry.clouds.unit_radius`). max_iterations,
    confidence: Open3D's RANSAC criteria. seed: Open3D's random seed. repeatable: one
    thread, so that a seed gives one answer. orient_normals: turn each cloud's normals
    towards its centroid before the features (Open3D's tutorial does not)."""

    voxel_size: float = 0.05
    max_iterations: int = 100_000
    confidence: float = 0.999
    seed: int = 0
    repeatable: bool = True
    orient_normals: bool = False

    def __post_init__(self) -> None:
        _positive("voxel_size", self.voxel_size, allow_none=False)
        _integer("max_iterations", self.max_iterations, 1)
        if not 0 < self.confidence <= 1:
            raise MaskNetError(f"confidence must be in (0, 1], got {self.confidence!r}")


@dataclass(frozen=True)
class FGROptions:
    """Open3D's fast global registration on FPFH features (``method="open3d-fgr"``):
    ``voxel_size`` as a fraction of the template's radius (``unit_radius``); ``orient_normals`` as
    :class:`RANSACOptions`'."""

    voxel_size: float = 0.05
    orient_normals: bool = False

    def __post_init__(self) -> None:
        _positive("voxel_size", self.voxel_size, allow_none=False)


HYPOTHESIS_SHARE = 16  # a source's points per point of the hypotheses' short ICP, at most


@dataclass(frozen=True)
class RobustOptions:
    """The options of ``method="auto"`` and ``"robust"``, the coarse-to-fine pipeline of
    :mod:`masknet.registration.stages.search`.

    feature_points: template points left by each FPFH voxel grid, in the order tried (the
        counts set the voxels, so the unit does not matter; a template of N > 1,024 points
        gets sqrt(N / 1,024) times as many, at most 8 times). The coarser grid first: it is
        cheaper, steadier where the clouds were sampled apart, the one whose matches hold on
        real scans of a few thousand points, and exact enough on shared points for the early
        exit; the finer one (about the template's own density) runs when it does not exit,
        and separates a symmetric shape's flips.
    ransac_trials: minimal samples of 3 matches per RANSAC run.
    correspondence_hypotheses: distinct poses each RANSAC run returns.
    compatibility_hypotheses: poses from groups of mutually compatible matches per grid
        (:func:`~masknet.registration.solvers.correspondences.compatible_poses`), where a grid has
        150 matches or more; 0 skips them.
    accept_fitness: stop after the correspondence hypotheses when the best one's fitness
        reaches this; 1.01 never stops early.
    hypotheses: starting rotations of the learned side (the 24 rotations of the cube,
        nearest the identity first; 0 skips them).
    hypothesis_points: points per cloud in the hypotheses' short ICP, at least; a source
        of more than 16 times as many points (after ``fine_points``) uses a sixteenth of
        them (:meth:`hypothesis_size`).
    max_iterations: ICP iterations per hypothesis.
    candidates: best-scoring distinct hypotheses refined at full resolution.
    inlier_iterations: ICP iterations of that refinement.
    max_correspondence_distance: its pair cut-off, in the clouds' units; None: 1.5
        template point spacings (unit-free).
    fine_points: source points (a seeded random subset of larger clouds) in the fit and
        the ICP refinement; the features see every point.
    distinct_deg: poses at least this far apart are different answers.
    ambiguity_margin: a different answer whose fitness is within this of the best makes
        the result ``ambiguous``.
    consensus_points: ``"auto"`` only: template points on the grid of the consensus front
        end (:mod:`masknet.registration.stages.consensus`); 0 skips it.
    consensus_from: ``"auto"`` only: templates of at least this many points have their
        shape measured before anything runs (docs/ARCHITECTURE.md, "The routing table":
        :mod:`masknet.registration.judge.shape`); those measured as scans try the consensus
        front end before the fast path, the pose as given judged first below 8 times as
        many points (:mod:`masknet.registration.stages.auto`). Smaller ones are measured
        only once the fast path has not held.
    consensus_below: ``"auto"`` only: sparse templates, of fewer points than this, try the
        consensus front end before the fast path (0: never). There the fast path holds on
        a fifth to a third of the pairs and the search costs 4-6 times the front end.
    search_first_turn_deg: ``"auto"`` only: objects (templates of ``consensus_below``
        points or more not measured as scans) whose source's principal axes are turned at least this
        far from the template's (:func:`masknet.geometry.clouds.principal_turn_deg`) go to
        the search first; the fast path, which starts from the pose as given, seldom holds
        there. None: never.
    object_accept_fitness: ``"auto"`` only: the fit at which the fast path's pose ends the
        call on objects (``accept_fitness`` on scans and sparse clouds). There a near-symmetric shape's flip fitted 0.990-0.992
        and right poses seldom fit under 0.993.
    """

    feature_points: tuple[int, ...] = (300, 1000)
    ransac_trials: int = 3000
    correspondence_hypotheses: int = 8
    compatibility_hypotheses: int = 10
    accept_fitness: float = 0.99
    hypotheses: int = 24
    hypothesis_points: int = 128
    max_iterations: int = 8
    candidates: int = 3
    inlier_iterations: int = 60
    max_correspondence_distance: float | None = None
    fine_points: int = 4096
    distinct_deg: float = 10.0
    ambiguity_margin: float = 0.02
    consensus_points: int = 1500
    consensus_from: int = 2048
    consensus_below: int = 1024
    search_first_turn_deg: float | None = 50.0
    object_accept_fitness: float = 0.993

    def __post_init__(self) -> None:
        grids = tuple(self.feature_points)
        if not grids or min(*grids, self.hypothesis_points, self.fine_points) < 16:
            raise MaskNetError(
                "robust: feature_points, hypothesis_points and fine_points must be >= 16"
            )
        for name in (
            "ransac_trials",
            "correspondence_hypotheses",
            "compatibility_hypotheses",
            "hypotheses",
            "candidates",
        ):
            _integer(name, getattr(self, name), 0)
        for name in (
            "hypothesis_points",
            "max_iterations",
            "inlier_iterations",
            "fine_points",
            "consensus_points",
            "consensus_from",
            "consensus_below",
        ):
            _integer(name, getattr(self, name), 0)
        if self.ransac_trials < 1 or self.correspondence_hypotheses < 0:
            raise MaskNetError("robust: ransac_trials >= 1, correspondence_hypotheses >= 0")
        if not 0 <= self.hypotheses <= 24:
            raise MaskNetError("robust: hypotheses must be in [0, 24]")
        if self.candidates < 1 or self.max_iterations < 1 or self.inlier_iterations < 0:
            raise MaskNetError(
                "robust: candidates >= 1, max_iterations >= 1 and inlier_iterations >= 0"
            )
        accepts = (self.accept_fitness, self.object_accept_fitness)
        accepted = all(_number(a) and 0 <= a <= 1.01 for a in accepts)
        if not accepted or not 0 <= self.ambiguity_margin <= 1:
            raise MaskNetError(
                "robust: accept_fitness and object_accept_fitness in [0, 1.01], "
                "ambiguity_margin in [0, 1]"
            )
        if 0 < self.consensus_points < 16:
            raise MaskNetError("robust: consensus_points must be 0 (off) or >= 16")
        if not 0 < self.distinct_deg <= 180:
            raise MaskNetError("robust: distinct_deg in (0, 180]")
        _positive("max_correspondence_distance", self.max_correspondence_distance)
        turn = self.search_first_turn_deg
        if turn is not None and (not _number(turn) or not 0 < turn <= 90):
            raise MaskNetError("robust: search_first_turn_deg in (0, 90], or None")

    def hypothesis_size(self, source_points: int) -> int:
        """Points per cloud in the hypotheses' short ICP for a source of ``source_points``:
        a fixed share of larger clouds. On 105 re-sampled 4,096-point scan views, 128
        points left 16 pairs over 5 degrees (mean 5.25) and 256 left 12 (mean 3.71), at
        the same median time: at 3% of the points, the short ICP from the right rotation
        stopped short of its basin."""
        return max(self.hypothesis_points, source_points // HYPOTHESIS_SHARE)

    def is_scan(self, template_points: int) -> bool:
        """Whether a template of ``template_points`` points is large enough to have its
        shape measured before anything runs, for ``"auto"``: ``consensus_from`` points or
        more (whether it is a scan is measured: :mod:`masknet.registration.judge.shape`).
        Called directly, :func:`~masknet.registration.stages.consensus.consensus_register`
        treats such a pair as a scan's: the finer grid's normals from within two voxels, a
        third cut, the plane-to-plane verdict, an unsure RANSAC questioned."""
        return template_points >= self.consensus_from

    def is_sparse(self, template_points: int) -> bool:
        """Whether a template of ``template_points`` points is sparse, for ``"auto"``:
        fewer than ``consensus_below``."""
        return template_points < self.consensus_below

    def is_object(self, template_points: int) -> bool:
        """Whether a template of ``template_points`` points lies between the sparse and the
        measured-first sizes: the size of ModelNet40's shapes, where the fast path's accept
        level and the principal axes' gate were measured. ``"auto"`` calls a template an
        object by its measured shape (:mod:`masknet.registration.judge.shape`)."""
        return not self.is_sparse(template_points) and not self.is_scan(template_points)

    def fast_accept(self, template_points: int) -> float:
        """The fit at which the fast path ends the call for a template of this size, by its
        size alone (``"auto"`` takes ``object_accept_fitness`` on the objects its route
        measures or has not measured yet)."""
        if self.is_object(template_points):
            return self.object_accept_fitness
        return self.accept_fitness

    def cut(self, spacing: float) -> float:
        """The pair cut-off in the clouds' units, for a template of this point spacing."""
        if self.max_correspondence_distance is not None:
            return float(self.max_correspondence_distance)
        return inlier_cutoff(spacing)


@dataclass(frozen=True)
class SceneSearch:
    """Options of the scene search (:func:`masknet.registration.stages.scene.locate`); lengths are
    in template radii (:func:`~masknet.geometry.clouds.unit_radius`: the largest distance
    of a template point from the centre of the template's bounding box), in a frame centred
    on the template's centroid.

    voxel: grid of the thinned scene. spacing: grid of the candidate centres. crop: radius
    of a candidate's region. min_region_points: smaller regions are skipped.
    hypotheses: rotations per centre (the cube's 24, nearest the identity first).
    hypothesis_points: template points in the batched hypothesis stage.
    max_iterations: ICP iterations of the placements, and twice as many in the refinement
    for the best quarter of its candidates (the others stop after 5) (Open3D's name;
    rounds are register's ``iterations``). trim: fraction of template
    points that score.
    candidates: best placements refined. refine_points: template points then.
    refine_distance: correspondence cut-off of the refinement.
    inlier_distance: scene points this close to the moved template are the object's (at
        least 1.5 times the template's median nearest-neighbour spacing).
    viewpoint: the sensor's position in the scene's coordinates (input units), e.g.
        (0, 0, 0) for a depth frame in camera coordinates. With it, only the template
        points that face the sensor (outward PCA normals towards it) need to lie on the
        scene, so a full 360-degree model can be found in a one-sided scan.
    max_placements: the most placements (centres x hypotheses) of the batched stage; a
        larger scene gets a coarser centre grid (reported as ``SceneMatch.spacing``).
    scene_ratio: :func:`is_scene` calls a source a scene when it is at least this many times
        as spread out as the template (median distance of the points from their median
        point: outliers, even a third of the points, barely move it).
    centre_share: the share of candidate centres searched: those whose surroundings look
        most like the template by FPFH features (at least 128; 1 searches all,
        :mod:`masknet.registration.stages.scene_centres`). feature_voxel: the features' grid.
    """

    voxel: float = 0.05
    spacing: float = 0.5
    crop: float = 1.5
    min_region_points: int = 32
    hypotheses: int = 24
    hypothesis_points: int = 64
    max_iterations: int = 15
    trim: float = 0.9
    candidates: int = 16
    refine_points: int = 1024
    refine_distance: float = 0.1
    inlier_distance: float = 0.02
    scene_ratio: float = 3.0
    max_placements: int = 50_000
    viewpoint: tuple[float, float, float] | None = None
    centre_share: float = 0.125
    feature_voxel: float = 0.2

    def __post_init__(self) -> None:
        from masknet.geometry.clouds import MIN_POINTS  # here: the method table needs no torch

        for name in ("voxel", "spacing", "crop", "refine_distance", "inlier_distance"):
            _positive(f"scene search: {name}", getattr(self, name), allow_none=False)
        _positive("scene search: feature_voxel", self.feature_voxel, allow_none=False)
        if not _number(self.centre_share) or not 0 < self.centre_share <= 1:
            raise MaskNetError(
                f"scene search: centre_share must be in (0, 1], got {self.centre_share!r}"
            )
        _positive("scene search: scene_ratio", self.scene_ratio, allow_none=False)
        if not _number(self.trim) or not 0 < self.trim <= 1:
            raise MaskNetError(f"scene search: trim must be in (0, 1], got {self.trim!r}")
        for name, low in (
            ("hypotheses", 1),
            ("hypothesis_points", MIN_POINTS),
            ("max_iterations", 1),
            ("min_region_points", 1),
            ("candidates", 1),
            ("refine_points", MIN_POINTS),
            ("max_placements", self.hypotheses),
        ):
            _integer(f"scene search: {name}", getattr(self, name), low)
        if self.viewpoint is not None and (
            np.shape(self.viewpoint) != (3,) or not np.isfinite(self.viewpoint).all()
        ):
            raise MaskNetError("scene search: viewpoint must be 3 finite numbers (x, y, z)")

    def check(self) -> None:
        """Kept for callers of the former NamedTuple: the values are checked when made."""
        self.__post_init__()

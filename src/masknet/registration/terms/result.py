"""What :func:`masknet.register` returns: :class:`RegistrationResult`, with Open3D's
names (``transformation``, ``fitness``, ``inlier_rmse``) beside masknet's own."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, NamedTuple, TypedDict

import numpy as np

from masknet.geometry.se3 import rotation_angle_deg

if TYPE_CHECKING:
    from masknet.registration.stages.scene import SceneMatch

__all__ = [
    "AUTO_INFO",
    "PIPELINE_INFO",
    "PipelineInfo",
    "RegistrationResult",
    "Solution",
    "info_arrays",
]


class PipelineInfo(TypedDict):
    """One pair's report of a pipeline (``"robust"``, ``"auto"``): the one list of its keys,
    in the order :attr:`RegistrationResult.info` holds them. path: which stage answered;
    source: the stage of the winning pose; fitness, inlier_rmse (input units), score: its
    fit (:class:`~masknet.registration.judge.fit.PoseFit`); ambiguous: a close runner-up lies
    elsewhere; runner_up_fitness, runner_up_score: that runner-up's fit (NaN where none);
    hypotheses: how many poses were scored; runner_up: its pose (4, 4), or None."""

    path: str
    source: str
    fitness: float
    inlier_rmse: float
    ambiguous: bool
    runner_up_fitness: float
    score: float
    runner_up_score: float
    hypotheses: int
    runner_up: np.ndarray | None


# The keys of a pipeline's info, and of "auto"'s (the fast path's fit that sent it on, NaN
# where it did not run or sufficed).
PIPELINE_INFO: tuple[str, ...] = tuple(PipelineInfo.__annotations__)
AUTO_INFO: tuple[str, ...] = (*PIPELINE_INFO, "escalated_fitness")


def info_arrays(pairs: list[PipelineInfo]) -> dict[str, np.ndarray]:
    """The info of a batch from each pair's: one array per key of :data:`PIPELINE_INFO`,
    (B,) each, ``runner_up`` (B, 4, 4) with NaN where a pair has none."""
    info = {key: np.array([p[key] for p in pairs]) for key in PIPELINE_INFO[:-1]}
    none = np.full((4, 4), np.nan)
    info["runner_up"] = np.stack(
        [none if p["runner_up"] is None else p["runner_up"] for p in pairs]
    )
    return info


class Solution(NamedTuple):
    """What a stage of a call found, before :func:`~masknet.register` turns it into a
    :class:`RegistrationResult` (the one inner result type: the search, the refinement, the
    rounds, the pipelines and the method all return it).

    transform: (4, 4) for one pair or (B, 4, 4) for a batch, float64, source -> template.
    mask: (N,) or (B, N) bool template points on the overlap, or None without masks.
    source_mask: (M,) or (B, M) bool source points kept, or None. info: the stage's report
    (a :class:`PipelineInfo`, or (B,) arrays per key; empty where the stage reports none).
    rounds: the transform after each round, (4, 4) or (B, 4, 4) each. inliers: (B, N) bool
    correspondence inliers of a correspondence method, or None."""

    transform: np.ndarray
    mask: np.ndarray | None = None
    source_mask: np.ndarray | None = None
    info: dict[str, Any] | None = None
    rounds: list[np.ndarray] | None = None
    inliers: np.ndarray | None = None


@dataclass
class RegistrationResult:
    """What :func:`register` returns. Arrays are numpy, float64 unless stated.

    The transform maps **source points into the template frame**,
    ``template ~= source @ R.T + t``; see :mod:`masknet.geometry.se3`. Shapes are
    given for one pair, with a leading batch dimension B for batched input.

    Attributes:
        R: (3, 3) or (B, 3, 3) rotation.
        t: (3,) or (B, 3) translation, in the input's units.
        transform: (4, 4) or (B, 4, 4), ``[[R, t], [0, 1]]``.
        mask: (N,) or (B, N) bool over the input template: the inliers used in the
            last round, or with a refiner (``iterations`` > 1) its mask at the pose the
            rounds reached (before ``refine_iterations``, a scene search's polish or the
            robust pipeline's inlier ICP move it further); None without a mask.
        times: seconds per stage, summed over rounds: ``"sample"`` (subsampling large
            clouds), ``"mask"`` (MaskNet), ``"register"`` (the method), ``"refine"``,
            ``"search"`` (with a scene search) and ``"total"`` (the whole call); ``"auto"``
            and ``"robust"`` add ``"fast"`` (the fast path's ICP and check), ``"route"``
            (``"auto"``'s measure of the template's shape) and ``"consensus"`` (its front end),
            ``"features"`` (FPFH), ``"ransac"`` (RANSAC and the early refinement),
            ``"hypotheses"`` and their ``"refine"``.
        info: what the method reported in its last run, as numpy arrays, () or (B,)
            each. ``"auto"`` and ``"robust"``: ``path``, ``source`` (of the winning
            hypothesis), ``fitness`` and ``inlier_rmse`` (of the kept source points within
            1.5 template spacings), ``score``, ``ambiguous``, ``runner_up`` ((4, 4), NaN
            where none), ``runner_up_fitness``, ``runner_up_score``, ``hypotheses``, and for
            ``"auto"`` ``escalated_fitness`` (the fast path's fit that sent it on; NaN where the fast path did
            not run or sufficed). ICP methods: ``converged``, ``iterations`` (-1 where not reported),
            ``fitness`` and ``inlier_rmse`` (Open3D's definitions). PointNetLK:
            ``converged``, ``iterations``, ``feature_residual``.
        rounds: the cumulative transform after each round, (4, 4) or (B, 4, 4) each.
        sampled: (template, source) sizes the method ran on, for single pairs (for
            ``auto`` and ``robust``, the sizes the networks saw; the clouds' own where no
            network ran).
        correspondence_inliers: (N,) or (B, N) bool, for PRNet and RPM-Net: the template
            points taking part in a confident correspondence in the last round (the rule
            is in :mod:`masknet.models.prnet` and :mod:`masknet.models.rpmnet`); template
            points the network did not see (sampled away for its input size) are False;
            None for other methods.
        source_mask: (M,) or (B, M) bool over the source: the points a two-sided MaskNet
            kept in the last round, or a refiner's at the pose the rounds reached (for a
            large single pair, each point takes the label of its nearest sampled point);
            None for one round of the paper's MaskNet and without a mask.
        method: the method that ran (the default resolved: ``"auto"``, or ``"icp"`` from a
            scene search's pose).
        scene: the scene search's :class:`~masknet.registration.stages.scene.SceneMatch` where one
            ran (its pose, the scene points on the object, ``coverage``, ``regions``,
            ``spacing``, ``seconds``), else None.
    """

    R: np.ndarray
    t: np.ndarray
    transform: np.ndarray
    mask: np.ndarray | None
    times: dict[str, float] = field(default_factory=dict)
    info: dict[str, np.ndarray] = field(default_factory=dict)
    rounds: list[np.ndarray] = field(default_factory=list)
    sampled: tuple[int, int] | None = None
    correspondence_inliers: np.ndarray | None = None
    source_mask: np.ndarray | None = None
    method: str = ""
    scene: SceneMatch | None = None

    # Open3D's names (``RegistrationResult`` of ``open3d.pipelines.registration``).
    def started_from(self, start: np.ndarray) -> RegistrationResult:
        """This result, found for a source moved by ``start`` (B, 4, 4), as a result for
        the source as given: every pose composed with ``start`` (``init`` as a matrix)."""
        single = self.transform.ndim == 2
        start_b = start if not single else start[0]
        transform = self.transform @ start_b
        info = dict(self.info)
        if "runner_up" in info:
            runner_up = np.asarray(info["runner_up"])
            info["runner_up"] = runner_up @ (start if runner_up.ndim == 3 else start[0])
        scene = self.scene
        if scene is not None:
            scene = scene._replace(transform=scene.transform @ start[0])
        return replace(
            self,
            R=transform[..., :3, :3],
            t=transform[..., :3, 3],
            transform=transform,
            rounds=[r @ start_b for r in self.rounds],
            info=info,
            scene=scene,
        )

    @property
    def transformation(self) -> np.ndarray:
        """Open3D's name for :attr:`transform`: (4, 4) or (B, 4, 4)."""
        return self.transform

    @property
    def fitness(self) -> np.ndarray | None:
        """Fraction of source points with a template point within the correspondence
        distance (Open3D's definition), () or (B,), at the pose the method returned: at its
        ``max_correspondence_distance``, or where none is given 1.5 template spacings, as
        :func:`~masknet.registration.evaluate_registration` measures any result. ``"auto"``
        and ``"robust"`` count the source points they keep; after a scene search, it is the
        method's on the object's points, before the final polish."""
        return self.info.get("fitness")

    @property
    def inlier_rmse(self) -> np.ndarray | None:
        """RMSE over those correspondences, in the input's units; None where not reported."""
        return self.info.get("inlier_rmse")

    @property
    def converged(self) -> bool | np.ndarray | None:
        """Whether the method's own stopping rule was met: a bool for one pair, (B,) bool
        for a batch; None where the method has no such rule (global registration, DCP)."""
        value = self.info.get("converged")
        if value is None:
            return None
        return bool(value) if np.ndim(value) == 0 else np.asarray(value, bool)

    @property
    def rotation_deg(self) -> np.ndarray:
        """The angle of ``R`` in degrees (:func:`~masknet.geometry.se3.rotation_angle_deg`):
        () or (B,)."""
        return rotation_angle_deg(self.R)

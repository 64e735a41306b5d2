"""``method="robust"``: coarse-to-fine registration of one pair from two kinds of hypotheses.

ICP, masked or not, stops in the nearest local minimum, so the pose it starts from decides
the result. This pipeline gathers starting poses from two sources that fail in different
places, scores them all with one fit, and refines only the best:

1. **Correspondences** (:mod:`masknet.registration.solvers.correspondences`). FPFH features on a
   voxel grid that leaves about ``feature_points`` template points (so the unit does not
   matter; normals turned towards each cloud's centroid), nearest-neighbour matches both
   ways, and a batched RANSAC that returns the ``correspondence_hypotheses`` best distinct
   poses; where a grid has 150 matches or more, ``compatibility_hypotheses`` more from
   groups of mutually compatible matches (found where too few matches are right for
   RANSAC to draw three). Strong on dense clouds and real scans, whatever the rotation.
2. **Early exit.** When the best of those fits as a correct result does (``fitness`` of at
   least ``accept_fitness`` at 1.5 template spacings, the measure of
   :func:`~masknet.registration.evaluate_registration`, over the source points that
   :func:`check_points` keeps), the search stops there. No network runs.
3. **The learned side**, otherwise. The two-sided MaskNet masks both clouds once (the
   template's overlap, the source's outliers). Matches that touch a rejected point are
   dropped and RANSAC runs again on the rest; and the kept source, centred on the masked
   template's centroid, starts from each of ``hypotheses`` rotations (the 24 rotations of
   the cube) through ``max_iterations`` of ICP at ``hypothesis_points`` points (a
   sixteenth of larger clouds). This is where sparse or re-sampled objects, whose FPFH
   features say little, are found.
4. **One score** for every hypothesis: the fitness of the kept source points against the
   whole template, from one KD-tree built once, ties broken by the inlier RMSE.
5. **Refinement of the best ``candidates``**, one per basin (``distinct_deg`` or a tenth
   of the template's radius apart): ``inlier_iterations`` of ICP on the kept source with
   pairs cut at ``max_correspondence_distance`` (1.5 template spacings); rescored, the
   best wins. The answer (after step 6) is refined once more from a looser cut-off
   (``SETTLE_CUT`` times it, then at it), and the refined pose replaces it where it fits
   better and the verdict calls it better (``arbiter.settled_better``).
6. **Ambiguity.** When answers fit within ``ambiguity_margin`` of the best, each is first
   refined as far as it goes (pairs cut at twice ``max_correspondence_distance``, then at it) and
   scored again; among those still alike, the least rotation from the pose as given
   wins. When a pose at least ``distinct_deg`` away still fits within the margin (a
   symmetric shape), the result says so (``info["ambiguous"]``, with the runner-up's
   transform and fitness).

Everything runs on one pair in numpy and KD-trees; stage times go to ``times``
(``features``, ``ransac``, ``mask``, ``hypotheses``, ``refine``).

Example::

    result = register(template, source, method="robust")
    result.info["path"], result.info["ambiguous"]
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from masknet.geometry.clouds import MIN_POINTS, centroid_radius
from masknet.geometry.knn import cloud_tree
from masknet.geometry.sampling import spread_labels
from masknet.geometry.se3 import hypothesis_rotations, transform_points
from masknet.io import has_open3d
from masknet.registration.judge import arbiter
from masknet.registration.judge.arbiter import Candidate
from masknet.registration.judge.assessment import judge
from masknet.registration.judge.fit import covered_points, pose_fit, pose_fits
from masknet.registration.solvers.correspondences import (
    FeatureCloud,
    compatible_poses,
    feature_cloud,
    mutual_matches,
    ransac_poses,
    voxel_for,
)
from masknet.registration.solvers.icp import icp, icp_from_starts
from masknet.registration.terms.options import RobustOptions
from masknet.registration.terms.result import PipelineInfo, Solution

if TYPE_CHECKING:
    from masknet.registration.stages.refinement import MaskPredictor
from masknet.registration.judge.prepared import (
    PreparedPair,
    random_subset,
)

__all__ = ["REFINE_TOLERANCE", "coarse_to_fine"]

# The refinement's ICP stops once its mean squared error changes by less than this
# fraction: finer steps move a pose by far less than its error.
REFINE_TOLERANCE = 5e-6


# The search's answer is refined once more from pairs cut at this many times the pair
# cut-off (then at it), and the result kept where it fits better and the verdict calls it
# better (_Search.settle). At the pair cut-off a room's partial views fit a pose turned some
# degrees as a local fit: on a re-sampled room view the answer stopped 8.2 degrees off
# (score 0.950), and ICP from it at 1 and 2 cut-offs stayed there (7.7 degrees); from 3, it
# reached 1.8 degrees (the truth, refined, scores 0.963). Kept by the score alone, the
# 3DMatch pair's answer slid 12 cm along the room's planes, which the verdict sees through.
SETTLE_CUT = 3.0


# Compatible groups of matches (:func:`compatible_poses`) join RANSAC's hypotheses where a
# grid has at least this many matches (templates of a few thousand points). On 105
# re-sampled 4,096-point scan views they took the first round's mean from 3.46 to 1.76
# degrees; on 512- and 1,024-point clouds (30-90 matches a grid) the groups are too small
# to agree by more than chance, and on re-sampled ModelNet40 shapes they took `robust`
# from 6.6 to 8.5 degrees.
COMPATIBILITY_MIN_MATCHES = 150


# Candidates for refinement lie in different basins: at least distinct_deg or this share
# of the template's radius (centroid_radius) apart. Poses closer than that refine into one answer, and a
# tighter test (1.5 template spacings) let three copies of one symmetric flip, a few
# spacings apart, fill every candidate place on a scan view whose true pose ranked fourth
# (returned 180 degrees off; with this test 5.8 degrees, refined to 0.1 by the loop).
CANDIDATE_BASIN = 0.1


# The early exit's check of the clouds as they are (:func:`_as_given`) refines them only
# when their short ICP fits at most this far below the best answer (the flipped pair's
# start: 0.920 against 0.967).
AS_GIVEN_GAP = 0.1


def coarse_to_fine(
    template: np.ndarray,
    source: np.ndarray,
    masks: MaskPredictor | None,
    options: RobustOptions,
    times: dict[str, float],
    prepared: PreparedPair | None = None,
) -> Solution:
    """The pipeline of the module docstring for template (N, 3) and source (M, 3), float64
    numpy, at any size: the features see the whole clouds, the fit and ICP the even
    subsets of the pair's fit view (:attr:`~masknet.registration.judge.prepared.PreparedPair.fit`;
    ``prepared``: the call's prepared pair of these clouds, None: one of its own).

    ``masks.predict_masks(template, source)`` gives the network's masks over the clouds
    it is given ((N,) and (M,) bool: the template's overlap, the source's kept points); None
    searches without masks."""
    search = _Search(template, source, options, times, prepared)
    early = search.correspondences()  # 1. hypotheses from FPFH matches; the early exit
    mask = source_mask = None
    if early is not None:
        finals = early + search.as_given_after_exit(early)
    else:  # 2. the learned side: both masks once, then masked matches and rotations
        if masks is not None:
            mask, source_mask = search.masks(masks)
        finals = search.hypotheses(mask)
    winner, rival, ambiguous = search.choose(finals)
    winner = search.settle(winner)
    transform = winner.pose
    if masks is not None:  # the template points the moved kept source covers
        # (also after an early exit, where the network never ran)
        mask = covered_points(
            template, transform_points(transform, search.kept_source), search.limit
        )
    if source_mask is not None and len(search.source) < len(source):
        # Each point of the whole source takes the label of its nearest subset point.
        source_mask = spread_labels(source, search.source, source_mask)
    info = PipelineInfo(
        path="correspondences" if early is not None else "search",
        source=winner.stage,
        fitness=winner.fitness,
        inlier_rmse=winner.rmse,
        ambiguous=bool(ambiguous),
        runner_up_fitness=float("nan") if rival is None else rival.fitness,
        score=winner.score,
        runner_up_score=float("nan") if rival is None else rival.score,
        hypotheses=len(search.scored),
        runner_up=None if rival is None else rival.pose,
    )
    return Solution(transform, mask, source_mask, info)


class _Search:
    """One pair's search: the prepared pair, every hypothesis scored so far (``scored``),
    and the stages of :func:`coarse_to_fine`, each a method. Stage times go to ``times``."""

    def __init__(
        self,
        template: np.ndarray,
        source: np.ndarray,
        options: RobustOptions,
        times: dict[str, float],
        prepared: PreparedPair | None,
    ) -> None:
        self.tic = time.perf_counter()
        if prepared is None:
            prepared = PreparedPair(template, source, options.fine_points)
        fit = prepared.fit
        self.prepared = prepared
        self.full_template, self.full_source = template, source
        self.template, self.tree, self.spacing, self.source = fit[:4]
        self.options, self.times = options, times
        self.limit = fit.limit
        self.radius = float(centroid_radius(self.template))
        # Isolated source points (uniform outliers, stray returns) would cap every pose's
        # fitness below what a correct pose reaches: the score counts the rest.
        self.surface, self.checked = fit.surface, fit.checked
        self.small = options.hypothesis_size(len(self.source))  # the hypotheses' short ICP
        self.probe = random_subset(self.source[self.surface], self.small * 2)
        self.kept_source = self.source[self.surface]
        self.scored: list[Candidate] = []
        # (source grid, template grid, their mutual matches), for the masked RANSAC
        self.grids: list[tuple[FeatureCloud, FeatureCloud, np.ndarray]] = []

    def clock(self, stage: str) -> None:
        """Add the seconds since the last clock to ``stage``."""
        now = time.perf_counter()
        self.times[stage] = self.times.get(stage, 0.0) + now - self.tic
        self.tic = now

    def refine(
        self, pose: np.ndarray, points: np.ndarray, kind: str, loose: float = 0.0
    ) -> Candidate:
        """ICP from ``pose`` with pairs cut at ``max_correspondence_distance`` (first at
        ``loose`` times that, where given), scored on ``points``. The tight cut-off alone
        can stop a few degrees short: from 3 degrees off a clean pair it settled 1.1 degrees
        off, where a looser one first reaches the exact pose."""
        tf, cut = pose, self.options.cut(self.spacing)
        for limit in ((loose * cut,) if loose else ()) + (cut,):
            tf = icp(
                self.template,
                points,
                tf,
                self.options.inlier_iterations,
                REFINE_TOLERANCE,
                max_correspondence_distance=limit,
                template_tree=self.tree,
            ).transform[0]
        return Candidate(tf, kind, pose_fit(self.tree, points, tf, self.limit))

    def settle(self, winner: Candidate) -> Candidate:
        """The search's answer ``winner`` refined from a looser cut-off (``SETTLE_CUT`` times
        the pair cut-off, then the cut-off), where it then fits better and the verdict on
        the pair's check view calls it better (:func:`~masknet.registration.judge.arbiter.settled_better`);
        else ``winner``. The verdict on ``winner`` is asked first: a ``likely correct``
        answer is not replaced, and its refined pose is then not judged."""
        settled = self.refine(winner.pose, self.kept_source, winner.stage, loose=SETTLE_CUT)
        self.clock("refine")
        if not arbiter.fits_better(settled, winner.score):
            return winner
        check = self.prepared.check()
        held = judge(check, winner.pose)
        better = arbiter.settled_better(lambda: judge(check, settled.pose), held)
        self.clock("refine")
        return settled if better else winner

    def score(self, poses: np.ndarray, points: np.ndarray, kinds: list[str] | str) -> None:
        """Score ``poses`` (H, 4, 4) on ``points`` and add them to the hypotheses."""
        kinds = [kinds] * len(poses) if isinstance(kinds, str) else kinds
        fits = pose_fits(self.tree, points, poses, self.limit)
        self.scored.extend(Candidate(p, k, f) for f, p, k in zip(fits, poses, kinds, strict=True))

    def correspondence_poses(self, grid: tuple, pairs: np.ndarray, kind: str) -> None:
        """RANSAC's best poses from the matches ``pairs`` of ``grid`` (and, with enough
        matches, poses of mutually compatible groups), scored on the probe points."""
        source_points, template_points = grid[0].points[pairs[:, 0]], grid[1].points[pairs[:, 1]]
        threshold = 1.5 * grid[0].voxel
        poses = ransac_poses(
            source_points,
            template_points,
            threshold,
            trials=self.options.ransac_trials,
            keep=self.options.correspondence_hypotheses,
        ).transform
        if len(pairs) >= COMPATIBILITY_MIN_MATCHES:
            compatible = compatible_poses(
                source_points,
                template_points,
                threshold,
                seeds=self.options.compatibility_hypotheses,
            )
            poses = np.concatenate([poses, compatible.transform])
        self.score(poses, self.probe, kind)

    def correspondences(self) -> list[Candidate] | None:
        """Correspondence hypotheses at each grid, in order, scored as RANSAC left them; the
        best two refined. The refined answers where one fits as a right pose does (the
        early exit), else None once every grid is done."""
        options = self.options
        if not (has_open3d() and options.correspondence_hypotheses):
            return None
        # A larger template gets finer grids: features of a room at an object's
        # resolution would see walls and little else. voxel_for's first try is in the
        # centroid radius, the consensus front end's in the RMS radius: one radius for both
        # would move both pipelines' voxels (docs/ARCHITECTURE.md, "One of each").
        growth = float(np.clip(np.sqrt(len(self.full_template) / 1024), 1, 8))
        voxels = [
            max(voxel_for(self.full_template, int(count * growth), self.radius), self.spacing)
            for count in options.feature_points
        ]
        for voxel in dict.fromkeys(voxels):  # two grids may come out alike on small clouds
            grid_s = feature_cloud(self.full_source, voxel)
            grid_t = feature_cloud(self.full_template, voxel)
            grid = (grid_s, grid_t, mutual_matches(grid_s.features, grid_t.features))
            self.grids.append(grid)
            self.clock("features")
            before = len(self.scored)
            self.correspondence_poses(grid, grid[2], "fpfh")
            early = self._exit_at(self.scored[before:]) if len(self.scored) > before else None
            self.clock("ransac")
            if early is not None:
                return early
        return None

    def _exit_at(self, found: list[Candidate]) -> list[Candidate] | None:
        """The two best distinct poses of one grid (``found``), refined, where one fits as a
        right pose does (``accept_fitness`` over the checked points); else None. A
        symmetric shape's flip can lead RANSAC's ranking, and a close second makes the
        answer ambiguous. A second that fits AS_GIVEN_GAP below the best is neither (it
        seldom climbs that far), and its refinement is skipped."""
        tops = arbiter.one_per_basin(arbiter.best_first(found), 2, self.limit)
        tops = arbiter.alike(tops, AS_GIVEN_GAP)
        refined = [self.refine(s.pose, self.kept_source, "fpfh") for s in tops]
        poses = np.stack([f.pose for f in refined])
        check = pose_fits(self.tree, self.source[self.checked], poses, self.limit)
        return refined if arbiter.exits(check, self.options.accept_fitness) else None

    def as_given_after_exit(self, early: list[Candidate]) -> list[Candidate]:
        """The clouds as they are, beside the early exit's answers (:func:`_as_given`)."""
        start = _short_icp_from_identity(
            self.template, self.kept_source, self.small, self.options.max_iterations
        )
        return _as_given(
            early, start, self.kept_source, self.tree, self.limit, self.options, self.refine
        )

    def masks(self, predictor: MaskPredictor) -> tuple[np.ndarray, np.ndarray]:
        """The network's masks, once; the kept source narrowed to them; RANSAC again on
        each grid's matches that touch no rejected point."""
        mask, source_mask = predictor.predict_masks(self.template, self.source)
        if (source_mask & self.surface).sum() >= MIN_POINTS:
            self.kept_source = self.source[source_mask & self.surface]
        else:
            source_mask = np.ones(len(self.source), bool)
        self.clock("mask")
        for grid in self.grids:
            keep_s = spread_labels(grid[0].points, self.source, source_mask)
            keep_t = spread_labels(grid[1].points, self.template, mask)
            masked = grid[2][keep_s[grid[2][:, 0]] & keep_t[grid[2][:, 1]]]
            if len(masked) >= MIN_POINTS:
                self.correspondence_poses(grid, masked, "fpfh-masked")
            self.clock("ransac")
        return mask, source_mask

    def hypotheses(self, mask: np.ndarray | None) -> list[Candidate]:
        """Every hypothesis through a short ICP at hypothesis resolution (the correspondence
        poses against the whole template, the rotations against the masked part), scored
        on the same kept points; the best few from different basins, refined."""
        options, small = self.options, self.small
        points = random_subset(self.kept_source, small * 2)
        src_small = random_subset(self.kept_source, small)
        whole_small = random_subset(self.template, small)
        if self.scored:
            found = np.stack([s.pose for s in self.scored])
            poses = icp_from_starts(
                cloud_tree(whole_small), whole_small, src_small, found, options.max_iterations
            )
            # Both as found and after the short ICP: on a large scene the ICP at
            # hypothesis resolution can move a good pose off.
            kinds = [s.stage for s in self.scored] * 2
            self.scored.clear()
            self.score(np.concatenate([found, poses]), points, kinds)
        # The clouds as they are: consecutive scans often start close.
        as_given = _short_icp_from_identity(
            self.template, self.kept_source, small, options.max_iterations
        )
        self.score(np.stack([np.eye(4), as_given]), points, "as given")
        target = self.template if mask is None or mask.sum() < MIN_POINTS else self.template[mask]
        target_small = random_subset(target, small)
        rotations = hypothesis_rotations(24)[: options.hypotheses]
        if len(rotations):
            starts = np.tile(np.eye(4), (len(rotations), 1, 1))
            starts[:, :3, :3] = rotations
            starts[:, :3, 3] = target.mean(0) - rotations @ src_small.mean(0)
            poses = icp_from_starts(
                cloud_tree(target_small), target_small, src_small, starts, options.max_iterations
            )
            self.score(poses, points, "rotation")
        self.clock("hypotheses")
        # The best few, refined with the pair cut-off, rescored on all kept points;
        # candidates from different basins (CANDIDATE_BASIN): close poses refine into one.
        self.scored = arbiter.best_first(self.scored)
        best_few = arbiter.one_per_basin(
            self.scored, options.candidates, CANDIDATE_BASIN * self.radius, options.distinct_deg
        )
        finals = [self.refine(s.pose, self.kept_source, s.stage) for s in best_few]
        self.clock("refine")
        return finals

    def choose(self, finals: list[Candidate]) -> tuple[Candidate, Candidate | None, bool]:
        """The answer among the refined ``finals``, the runner-up (a pose ``distinct_deg``
        or more away), and whether the choice is ambiguous (the runner-up fits within
        ``ambiguity_margin``): :func:`~masknet.registration.judge.arbiter.search_choice`.

        Refined answers that met in one basin are one answer. Among answers that fit
        alike, the least rotation from the pose as given wins: the data cannot choose, and
        the input is the only other evidence. Before the input decides, the fits each
        answer reaches when refined as far as it goes (a looser cut-off first) rank them;
        the answers keep their poses and their own fits, as a looser cut-off can also move
        a right pose on a partial scan."""
        options = self.options
        if not finals:  # no hypothesis at all (too few points for features): the identity
            fit = pose_fit(self.tree, self.kept_source, np.eye(4), self.limit)
            finals = [Candidate(np.eye(4), "identity", fit)]

        def refined_score(f: Candidate) -> float:
            return self.refine(f.pose, self.kept_source, f.stage, loose=2.0).score

        return arbiter.search_choice(
            finals, options.ambiguity_margin, options.distinct_deg, self.limit, refined_score
        )


def _short_icp_from_identity(
    template: np.ndarray, source: np.ndarray, points: int, iterations: int
) -> np.ndarray:
    """(4, 4): ``iterations`` of ICP from the identity on at most ``points`` of each cloud
    (template (N, 3), source (M, 3)): the clouds as they are, at hypothesis resolution."""
    src_small = random_subset(source, points)
    whole_small = random_subset(template, points)
    return icp_from_starts(
        cloud_tree(whole_small), whole_small, src_small, np.eye(4)[None], iterations
    )[0]


def _as_given(
    early: list[Candidate],
    start: np.ndarray,
    kept_source: np.ndarray,
    tree: Any,
    limit: float,
    options: RobustOptions,
    refine: Callable[[np.ndarray, np.ndarray, str], Candidate],
) -> list[Candidate]:
    """The clouds as they are (``start``, their short ICP from the identity), refined: one
    more answer beside the early exit's where it fits better than they do. A symmetric
    shape's flip can pass the early exit (a noisy ModelNet40 pair: the flip fit 0.992 of
    its points, the truth 1.0; scores 0.967 and 0.990), and only an answer found can be
    weighed against it. Not refined when ``start`` lies in an early answer's basin or fits
    ``AS_GIVEN_GAP`` below the best (it seldom climbs that far); not kept when it fits no
    better, since a nearby local fit within the ambiguity margin would otherwise win as
    the least rotation (with noise sigma 0.02, a mean of 2.84 degrees instead of 2.31)."""
    if arbiter.in_basin_of(start, early, options.distinct_deg):
        return []  # the early exit's own basin
    best = arbiter.best_score(early)
    if not arbiter.within_gap(pose_fit(tree, kept_source, start, limit).score, best, AS_GIVEN_GAP):
        return []
    found = refine(start, kept_source, "as given")
    return [found] if arbiter.fits_better(found, best) else []

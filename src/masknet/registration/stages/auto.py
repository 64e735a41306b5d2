"""``method="auto"``, the default: the stages of one pair, in the order they run, each
with the condition under which it runs. Each choice between poses is a rule of
:mod:`masknet.registration.judge.arbiter`.

0. **Scene search** (before this module, in :mod:`masknet.registration.pipeline`), for
   one pair whose source is ``scene_ratio`` (3) times as spread out as the template
   (:func:`~masknet.registration.stages.scene.is_scene`): :func:`~masknet.registration.stages.scene.locate`
   finds the template in the scene, and Mask-ICP (``"icp"``) from the pose found, then
   the polish at full resolution, run instead of the stages below: path
   ``"scene search"``. Where it finds nothing to register, the stages below run.
1. **Route** (docs/ARCHITECTURE.md, "The routing table"). A template of fewer than
   ``consensus_below`` points is sparse; any other is a scan (an open surface seen from
   one side, or a scene scanned from within) or an object (a closed shape), as
   :func:`~masknet.registration.judge.shape.classify_template` measures it, with the
   thresholds of :data:`~masknet.registration.judge.shape.SHAPE`. From
   ``consensus_from`` points the shape is measured before anything runs; between the
   two sizes only once the fast path has not held, and fitted under ``partial_fit``
   (stage 4b): the measure costs about 8 ms, most objects there end on the fast path,
   and a fifth of ModelNet40's thin shapes read as one-sided.
2. **Consensus front end**, for scans and sparse clouds (``consensus_points`` > 0)
   (:mod:`masknet.registration.stages.consensus`: a voxel budget, RANSAC on FPFH matches,
   point-to-plane ICP, the verdict). The pose as given is refined and judged first
   (``start="first"``: a ``likely correct`` pose ends the call before the features and
   RANSAC; an ``uncertain`` one is slid to cover more of both clouds, refined and judged
   again, ``arbiter.covers_more``), except on scans of ``CONSENSUS_FIRST`` times
   ``consensus_from`` points or more (that large it is seldom right, and its refinement
   costs what RANSAC does); else it competes with RANSAC's poses (a symmetric shape fits
   a flip as well). A
   ``likely correct`` answer (``arbiter.settles``) ends the call: path ``"consensus"``.
   On views of objects in real scans the pose as given, refined, ends most calls at a
   third of the fast path's cost; on sparse clouds the fast path holds on a fifth to a
   third of the pairs and the search costs 4-6 times the front end.
3. **Principal-axes gate**, for objects and templates not yet measured
   (``search_first_turn_deg`` not None): a source
   whose principal axes are turned ``search_first_turn_deg`` or more from the
   template's goes to the search (stage 5) without the fast path, which starts from the
   pose as given and seldom holds that far off.
4. **Fast path**, otherwise. One round of the paper's Mask-ICP on the networks' clouds
   (MaskNet's template mask, by default the small ``masknet_modelnet40_small``; the
   source centroid onto the masked template's centroid, 10 iterations of ICP), then ICP
   with pairs cut at ``max_correspondence_distance`` (1.5 template spacings) on the
   pair's fit view (:attr:`masknet.registration.judge.prepared.PreparedPair.fit`: even subsets),
   and the check: the share of the source's surface points within 1.5 template spacings
   of the template (:func:`masknet.registration.judge.fit.pose_fit`). Stray outliers do not
   count: points without two others within 2 template spacings, and points beside a
   surface (no other point within 1.5 spacings, off their neighbours' plane), each test
   unless it drops over 5% of the points
   (:func:`masknet.registration.judge.prepared.check_points`). A fit of at least
   ``accept_fitness`` (``object_accept_fitness`` on objects, where a near-symmetric
   shape's flip fits 0.990) ends the call (``arbiter.accepts``): path ``"fast"``. A pose
   that fits but was still moving when ICP's iterations ran out gets them once more.
   4b. **Measured late**: a template between the sizes whose fast path fitted under
   ``partial_fit`` (``arbiter.partial_overlap``: two partial clouds) is measured now; a
   scan's runs the consensus front end (the scan's settings, the pose as given judged
   first), whose pose then competes with the search's (stage 6). Where the principal
   axes sent the pair to the search (stage 3), the search's answer's fit decides, after
   stage 5: taken as partial unseen, 16 of 100 ModelNet40 pairs turned up to 180 degrees
   ran the front end for nothing (median 23 -> 36 ms).
5. **Search**, where the fast path's fit is lower (or the gate sent the pair): the
   coarse-to-fine pipeline of ``method="robust"``
   (:mod:`masknet.registration.stages.search`) on the same prepared pair: path
   ``"robust/correspondences"`` (its early exit) or ``"robust/search"``; its answer is
   refined once more from a looser cut-off and replaced where the verdict calls that
   better (``arbiter.settled_better``). The fast path's pose takes part: where it fits better (``arbiter.fits_better``) it is the
   answer after all (path ``"fast"``), ambiguous where one of the search's poses lies
   elsewhere and fits about as well (``arbiter.close_rival``).
6. **The front end's pose against the answer**, where the front end ended without
   settling and its pose competes (``arbiter.may_compete``): on every route where its one
   fault is that the clouds leave it free (``arbiter.only_free``: it fits as right poses
   do and no slide fits better, but the slide search does not look along a free turn), and
   on scans where it is ``uncertain`` (after stage 4b also ``likely correct``; there only
   a better verdict, ``arbiter.better_verdict``, replaces the search's answer: a thin
   object reads as one-sided, and the search's pose is exact). The verdict judges the
   answer of stage 4 or 5, and the front end's pose replaces it where it ranks higher
   (``arbiter.ranks_higher``; the search's one-way score can prefer a pose slid along a
   wall): path ``"consensus"`` over the fast path's answer, ``"robust/consensus"`` over
   the search's. Not otherwise on sparse clouds: there the verdict rated right search
   answers below consensus poses 60-180 degrees off.

The networks' clouds are sampled on first use, so a call the consensus ends never
samples them. ``info`` holds :data:`~masknet.registration.terms.result.AUTO_INFO`: ``path``
says which stage answered (:data:`PATHS`) and ``escalated_fitness`` the fast path's fit
that sent the pair on (NaN where the fast path did not run or sufficed).
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from masknet.geometry.clouds import MIN_POINTS
from masknet.geometry.sampling import NetworkClouds, spread_labels
from masknet.geometry.se3 import transform_points
from masknet.models.masknet import MaskNet
from masknet.models.two_sided import TwoSidedMaskNet
from masknet.registration.judge import arbiter
from masknet.registration.judge.arbiter import Candidate
from masknet.registration.judge.assessment import Assessment, judge
from masknet.registration.judge.fit import PoseFit, covered_points, pose_fit
from masknet.registration.judge.prepared import PreparedPair, check_points
from masknet.registration.judge.shape import SHAPE
from masknet.registration.solvers.backends.base import MaskModels
from masknet.registration.solvers.icp import icp
from masknet.registration.stages import consensus as front_end
from masknet.registration.stages.robust import GivenMasks, NetworkMasks, pipeline_run
from masknet.registration.stages.rounds import mask_and_register
from masknet.registration.stages.route import Route, turned_first
from masknet.registration.stages.search import REFINE_TOLERANCE, coarse_to_fine
from masknet.registration.terms.options import ICPCriteria, RobustOptions
from masknet.registration.terms.result import PipelineInfo, Solution, info_arrays

__all__ = ["PATHS", "auto_register"]

# Every ``info["path"]`` of the default: its own paths, then the scene search's (set where
# the call left the scan, masknet.registration.pipeline). The README lists them all.
PATHS = (
    "fast",
    "consensus",
    "robust/consensus",
    "robust/correspondences",
    "robust/search",
    "scene search",
)

# Scans of this many times ``consensus_from`` points skip the pose as given in the consensus
# front end: that large, it is seldom right, and its refinement costs what RANSAC does.
CONSENSUS_FIRST = 8


def auto_register(
    template: np.ndarray,
    source: np.ndarray,
    nets: NetworkClouds,
    models: MaskModels,
    options: RobustOptions,
    times: dict[str, float],
    precision: str = "auto",
) -> Solution:
    """The pipeline of the module docstring for template (B, N, 3) and source (B, M, 3),
    float64, pair by pair, at full resolution; the networks see ``nets`` (B, n, 3) and
    (B, m, 3), the clouds sampled to their size on first use. ``models.first`` masks the fast
    path (None: plain ICP), ``models.search`` the escalation (None: no mask). Masks are over
    the full clouds. The method table's adapter of ``"auto"``."""
    model, search_model = models
    runs = []
    for b in range(template.shape[0]):
        pair_nets = _PairNets(nets, b)
        runs.append(
            _one(template[b], source[b], pair_nets, model, search_model, options, times, precision)
        )
    info = {key: np.concatenate([r.info[key] for r in runs]) for key in runs[0].info}

    def stacked(parts: list) -> np.ndarray | None:
        return None if any(p is None for p in parts) else np.concatenate(parts)

    return Solution(
        np.concatenate([r.transform for r in runs]),
        stacked([r.mask for r in runs]),
        stacked([r.source_mask for r in runs]),
        info,
    )


def _one(
    template: np.ndarray,
    source: np.ndarray,
    nets: _PairNets,
    model: MaskNet | TwoSidedMaskNet | None,
    search_model: TwoSidedMaskNet | None,
    options: RobustOptions,
    times: dict[str, float],
    precision: str,
) -> Solution:
    """One pair: template (N, 3), source (M, 3); ``nets`` the clouds the networks see. The
    pair is prepared once here, and every stage and the verdict read its views."""
    clouds = template, source
    pair = PreparedPair(template, source, options.fine_points)
    route = Route.first(template, options, times)
    consensus = None
    if route.on and (route.sparse or route.scan):
        large = len(template) >= CONSENSUS_FIRST * options.consensus_from  # see the constant
        start = "never" if large else "first"
        consensus = front_end.consensus_register(*clouds, options, times, start, pair, route.scan)
        if consensus is not None and arbiter.settles(consensus.check):
            return _consensus_run(consensus, pair, options, route.scan, model, "consensus")
    fast = None
    if not turned_first(template, source, options, route):  # the fast path starts from the pose
        accept = options.object_accept_fitness if route.dense_object else options.accept_fitness
        fast = _fast_path(pair, nets, model, options, times, precision, accept)
        if fast.accepted is not None:
            return _against_consensus(fast.accepted, consensus, pair, options, route, model)
    late = route.shape is None and not route.sparse  # most objects ended above

    def measured_late(fitness: float) -> tuple[Route, Candidate | None]:
        """Stage 4b: where a pose laid under ``partial_fit`` of the source on the template
        (both clouds partial), the template measured now, and a scan's front end run."""
        if not (late and route.on and arbiter.partial_overlap(fitness, SHAPE.partial_fit)):
            return route, consensus
        measured = route.measured(template, options, times)
        if not measured.scan:
            return measured, consensus
        return measured, front_end.consensus_register(*clouds, options, times, "first", pair, True)

    if fast is not None:  # the fast path's fit tells
        route, consensus = measured_late(fast.right)
    run = _escalate(pair, nets, fast, model, search_model, options, times, precision)
    if fast is None:  # turned by its principal axes: the search's answer's fit tells
        route, consensus = measured_late(_checked_fitness(pair, run.transform[0]))
    return _against_consensus(run, consensus, pair, options, route, model, late)


def _check_fitness(
    tree: object,
    checked: np.ndarray,
    kept: np.ndarray,
    pose: np.ndarray,
    limit: float,
    kept_fit: PoseFit | None = None,
) -> float:
    """The fast path's check of ``pose`` (4, 4): the share of the ``checked`` source points
    (P, 3) within ``limit`` of the template (its KD-tree ``tree``); of the ``kept`` ones
    (K, 3) where fewer than three are checked (the verdict counts only points with
    neighbours enough), ``kept_fit`` their fit where already measured."""
    if len(checked) >= 3:
        return pose_fit(tree, checked, pose, limit).fitness
    return (kept_fit or pose_fit(tree, kept, pose, limit)).fitness


def _checked_fitness(pair: PreparedPair, pose: np.ndarray) -> float:
    """:func:`_check_fitness` of ``pose`` (4, 4) on the pair's fit view."""
    view = pair.fit
    checked, kept = view.source[view.checked], view.source[view.surface]
    return _check_fitness(view.tree, checked, kept, pose, view.limit)


def _against_consensus(
    run: Solution,
    consensus: Candidate | None,
    pair: PreparedPair,
    options: RobustOptions,
    route: Route,
    model: MaskNet | TwoSidedMaskNet | None,
    late: bool = False,
) -> Solution:
    """Stage 6 of the module docstring: the answer ``run`` of the fast path or the search,
    or the front end's pose ``consensus`` (judged, not settled) where it competes and the
    verdict ranks it higher. It competes where it is only free
    (:func:`~masknet.registration.judge.arbiter.only_free`), and on scans where
    :func:`_competes`: the search's one-way score can prefer a pose slid along a wall that
    the verdict sees through. Not otherwise on sparse clouds: there the verdict called right
    search answers worse than consensus poses 60-180 degrees off."""
    if consensus is None:
        return run
    if not (arbiter.only_free(consensus.check) or route.scan and _competes(consensus.check, late)):
        return run
    grids = front_end.consensus_grids(pair, options, route.scan)
    answer = judge(grids.check, run.transform[0])
    if late:  # a thin object reads as one-sided: the search's exact pose is kept
        wins = arbiter.better_verdict(consensus.check, answer)
    else:
        wins = arbiter.ranks_higher(consensus.check, answer)
    if not wins:
        return run
    escalated = float(run.info["escalated_fitness"][0])
    path = "consensus" if np.isnan(escalated) else "robust/consensus"
    return _consensus_run(consensus, pair, options, route.scan, model, path, escalated)


def _competes(check: Assessment, late: bool) -> bool:
    """Whether the front end's pose competes with the search's answer: ``uncertain``
    (:func:`~masknet.registration.judge.arbiter.may_compete`), or, measured late, also
    ``likely correct`` (there it has not ended the call)."""
    return arbiter.may_compete(check) or (late and arbiter.settles(check))


class _PairNets(NamedTuple):
    """Pair ``b`` of the networks' clouds, sampled when first asked for."""

    nets: NetworkClouds
    b: int

    def clouds(self) -> tuple[np.ndarray, np.ndarray]:
        """(1, n, 3) and (1, m, 3)."""
        b = self.b
        return self.nets.template[b : b + 1], self.nets.source[b : b + 1]


class _Fast(NamedTuple):
    """The fast path: its result where it fits (``accepted``), else what the escalation
    uses: its transform (4, 4), fit, the check's fitness and masks."""

    accepted: Solution | None
    transform: np.ndarray
    fit: PoseFit
    right: float
    mask: np.ndarray | None
    source_mask: np.ndarray | None


def _fast_path(
    pair: PreparedPair,
    nets: _PairNets,
    model: MaskNet | TwoSidedMaskNet | None,
    options: RobustOptions,
    times: dict[str, float],
    precision: str,
    accept: float,
) -> _Fast:
    """Stage 4 of the module docstring: Mask-ICP on the networks' clouds, ICP with the
    pair cut-off on the pair's fit view, and the check of its fit (``accept`` ends the call)."""
    template, source = pair.template, pair.source
    icp_options = ICPCriteria()  # the paper's Mask-ICP: 10 iterations, all pairs
    template_net, source_net = nets.clouds()
    fast = mask_and_register(
        template_net, source_net, "icp", model, 1, icp_options, times, precision=precision
    )
    tic = time.perf_counter()
    prepared = pair.fit
    fine_template, tree, spacing, fine, surface = prepared[:5]
    limit = prepared.limit  # the fit's cut-off, on the prepared pair
    source_mask = None
    if fast.source_mask is not None:  # a two-sided network: its kept points, spread
        source_mask = spread_labels(source, source_net[0], fast.source_mask[0])
        kept_fine = spread_labels(fine, source_net[0], fast.source_mask[0]) & surface
        surface = kept_fine if kept_fine.sum() >= MIN_POINTS else surface
    kept = fine[surface]
    # The check's points among those kept (a two-sided network's mask narrows both).
    narrowed = surface is not prepared.surface
    checked = fine[
        check_points(surface, prepared.strict, prepared.attached) if narrowed else prepared.checked
    ]

    def refined(start: np.ndarray) -> tuple[np.ndarray, PoseFit, float, bool]:
        """ICP with the pair cut-off from ``start``: the pose, its fit, the check's
        fitness, and whether ICP converged within its iterations."""
        sol = icp(
            fine_template,
            kept,
            start,
            options.inlier_iterations,
            REFINE_TOLERANCE,
            max_correspondence_distance=options.cut(spacing),
            template_tree=tree,
        )
        pose, converged = sol.transform[0], bool(sol.converged[0])
        fit = pose_fit(tree, kept, pose, limit)
        return pose, fit, _check_fitness(tree, checked, kept, pose, limit, fit), converged

    transform, fit, right, converged = refined(fast.transform[0])
    if arbiter.accepts(right, accept) and not converged and options.inlier_iterations:
        # Still moving when its iterations ran out, from a start far off: a pose that fits
        # is let settle (on a copy pair it stopped 0.23 degrees short, one step from exact),
        # and kept where it still fits.
        settled = refined(transform)
        if arbiter.accepts(settled[2], accept):
            transform, fit, right, converged = settled
    times["fast"] = times.get("fast", 0.0) + time.perf_counter() - tic
    accepted = None
    if arbiter.accepts(right, accept):
        mask = None
        if model is not None:  # the template points the moved source covers: every
            # source point a two-sided network keeps (the fine grid's surface drops a rim)
            seen = source if source_mask is None else source[source_mask]
            seen = seen if len(seen) >= MIN_POINTS else kept
            moved = transform_points(transform, seen)
            # The fit view holds the whole template, in order, up to its budget: its tree
            # is this template's (a second one cost 4% of a ModelNet40 fast path).
            whole = tree if len(fine_template) == len(template) else None
            mask = covered_points(template, moved, limit, whole)[None]
        info = _info("fast", fit, np.nan)
        accepted = Solution(
            transform[None], mask, None if source_mask is None else source_mask[None], info
        )
    fast_mask = None if fast.mask is None else fast.mask[0]
    return _Fast(accepted, transform, fit, right, fast_mask, fast.source_mask)


def _escalate(
    pair: PreparedPair,
    nets: _PairNets,
    fast: _Fast | None,
    model: MaskNet | TwoSidedMaskNet | None,
    search_model: TwoSidedMaskNet | None,
    options: RobustOptions,
    times: dict[str, float],
    precision: str,
) -> Solution:
    """Stage 5 of the module docstring: the coarse-to-fine search, the fast path's pose one
    more answer (``fast`` None: a pair the principal-axes gate sent to the search)."""
    reuse = fast is not None and fast.mask is not None
    if search_model is not None and search_model is model and reuse:
        # The fast path's network is the search's: its masks serve again.
        search_model = GivenMasks(fast.mask, fast.source_mask)
    masks = None
    if search_model is not None:
        template_net, source_net = nets.clouds()
        masks = NetworkMasks(search_model, template_net[0], source_net[0], precision)
    found = coarse_to_fine(pair.template, pair.source, masks, options, times, pair)
    run = pipeline_run([found])
    if fast is not None and arbiter.fits_better(_fast_candidate(fast), run.info["score"][0]):
        return _fast_after_all(run, fast, options)  # the fast path fits better
    info = dict(run.info)
    info["path"] = np.array([f"robust/{run.info['path'][0]}"])
    info["escalated_fitness"] = np.array([np.nan if fast is None else fast.right])
    return Solution(run.transform, run.mask, run.source_mask, info)


def _fast_candidate(fast: _Fast) -> Candidate:
    """The fast path's pose as a candidate, with its fit."""
    return Candidate(fast.transform, "fast", fast.fit)


def _searched(run: Solution) -> list[Candidate]:
    """The search's answer and, where it has one, its runner-up, as candidates (their
    fitness and score from ``run.info``; the runner-up's RMSE is not reported: NaN)."""
    info = run.info
    fit = PoseFit(info["fitness"][0], info["inlier_rmse"][0], info["score"][0])
    found = [Candidate(run.transform[0], "search", fit)]
    if np.isfinite(info["runner_up"][0]).all():
        fit = PoseFit(info["runner_up_fitness"][0], np.nan, info["runner_up_score"][0])
        found.append(Candidate(info["runner_up"][0], "runner-up", fit))
    return found


def _fast_after_all(run: Solution, fast: _Fast, options: RobustOptions) -> Solution:
    """The fast path's pose, which fits better than the search's answer; ambiguous where
    one of the search's answers lies elsewhere and fits about as well
    (:func:`~masknet.registration.judge.arbiter.close_rival`)."""
    transform = fast.transform
    info = _info("fast", fast.fit, fast.right)
    rival = arbiter.close_rival(
        _fast_candidate(fast), _searched(run), options.distinct_deg, options.ambiguity_margin
    )
    if rival is not None:
        info["ambiguous"] = np.array([True])
        info["runner_up"] = rival.pose[None].copy()
        info["runner_up_fitness"] = np.array([rival.fitness])
        info["runner_up_score"] = np.array([rival.score])
    return Solution(transform[None], run.mask, run.source_mask, info)


def _consensus_run(
    found: Candidate,
    pair: PreparedPair,
    options: RobustOptions,
    scan: bool | None,
    model: MaskNet | TwoSidedMaskNet | None,
    path: str,
    escalated: float = np.nan,
) -> Solution:
    """The consensus front end's answer as the pipeline's result (``escalated``: the fast
    path's fit where it ran before): its fit on the grids it was judged on (``scan`` as the
    front end took it); with a network, the template points the moved source covers
    (measured on that grid: over the full clouds it cost more than the whole front end on
    1M points), and with a two-sided one the source points the pose lays on the template."""
    grids = front_end.consensus_grids(pair, options, scan)
    grid_template, grid_source = grids.template_grid, grids.source_grid
    tree, limit = grids.template_fit()
    fit = pose_fit(tree, grid_source, found.pose, limit)
    mask = source_mask = None
    if model is not None:  # on the grid, each template point taking its grid point's label
        moved = transform_points(found.pose, grid_source)
        covered = covered_points(grid_template, moved, limit)
        mask = spread_labels(pair.template, grid_template, covered)[None]
        if isinstance(model, TwoSidedMaskNet):
            on_template = covered_points(moved, grid_template, limit)
            source_mask = spread_labels(pair.source, grid_source, on_template)[None]
    return Solution(found.pose[None], mask, source_mask, _info(path, fit, escalated, "consensus"))


def _info(path: str, fit: PoseFit, escalated: float, source: str = "fast") -> dict[str, np.ndarray]:
    """The info (:data:`~masknet.registration.terms.result.AUTO_INFO`) of a result that is not
    the search's (``source``: the fast path's or the front end's): one pose, no runner-up."""
    pair = PipelineInfo(
        path=path,
        source=source,
        fitness=fit.fitness,
        inlier_rmse=fit.rmse,
        ambiguous=False,
        runner_up_fitness=np.nan,
        score=fit.score,
        runner_up_score=np.nan,
        hypotheses=1,
        runner_up=None,
    )
    return {**info_arrays([pair]), "escalated_fitness": np.array([escalated])}

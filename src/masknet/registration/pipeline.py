"""The stages of one :func:`masknet.register` call, each a function of a few named values.

``register`` reads as this list (see ``docs/ARCHITECTURE.md``, "What a register call does")::

    plan = plan_call(method, options, model, ...)   # the method and its checked options
    clouds = check_clouds(template, source, plan)   # every check of the clouds, once
    pair, plan = enter_frame(clouds, plan, times)   # scene search, networks, frame, sampling
    found = run_method(pair, plan, times)           # the method (and its rounds)
    found = refine_plain(pair, found, plan, times)  # refine_iterations of plain ICP
    found = measure_fit(pair, found, plan)          # Open3D's fitness of the pose, once
    return leave_frame(pair, found, plan, times)    # input units, the scene, masks spread

Arrays are numpy float64 batches (B, ...) from :func:`enter_frame` on; a single pair is a
batch of one until :func:`leave_frame` takes the batch axis off again.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, NamedTuple

import numpy as np

from masknet.errors import MaskNetError
from masknet.geometry.clouds import MIN_POINTS, SPACING_SAMPLE, Frame, median_spacing
from masknet.geometry.prepared_template import active
from masknet.geometry.sampling import NetworkClouds, fit_to_network, spread_mask
from masknet.geometry.se3 import transform_points
from masknet.registration.judge.fit import inlier_fit
from masknet.registration.plan import CallPlan, with_networks
from masknet.registration.solvers.backends.base import MaskModels
from masknet.registration.stages.refinement import refine_pose
from masknet.registration.stages.rounds import mask_and_register
from masknet.registration.stages.scene import SceneMatch, SceneSearch, is_scene, locate, polish
from masknet.registration.terms.methods import METHOD_TABLE, adapter
from masknet.registration.terms.options import ICPCriteria
from masknet.registration.terms.result import RegistrationResult, Solution
from masknet.registration.terms.units import warn_mixed_units
from masknet.registration.terms.validation import as_numpy_batch, finite_rows, spread_rows

__all__ = [
    "CheckedClouds",
    "FramedPair",
    "REFINE_POINTS",
    "check_clouds",
    "enter_frame",
    "leave_frame",
    "measure_fit",
    "refine_plain",
    "run_method",
]

# The most points of each cloud the refiner sees in the rounds after a pipeline.
REFINE_POINTS = 4096


class FramedPair(NamedTuple):
    """The pair as every stage after :func:`enter_frame` sees it.

    frame: the call's :class:`~masknet.geometry.clouds.Frame`. template, source: (B, N, 3)
    and (B, M, 3) in the frame, the source reduced to the scene points on the object
    after a scene search. nets: the clouds at the networks' size, sampled on first use
    (:class:`~masknet.geometry.sampling.NetworkClouds`); its parts are the properties
    sampled_template, sampled_source (the same arrays when nothing was sampled),
    template_index and source_index (the sampled rows, or None). single: one pair was given. template_input: (B, N, 3) the
    template in input units. template_rows, source_rows: (N0,), (M0,) bool input rows kept
    by ``drop_nonfinite``, or None. scene: the search's :class:`SceneMatch` and the whole
    scene (M0', 3) in input units, or None."""

    frame: Frame
    template: np.ndarray
    source: np.ndarray
    nets: NetworkClouds
    single: bool
    template_input: np.ndarray
    template_rows: np.ndarray | None
    source_rows: np.ndarray | None
    scene: tuple[SceneMatch, np.ndarray] | None

    @property
    def sampled_template(self) -> np.ndarray:
        return self.nets.sampled[0]

    @property
    def sampled_source(self) -> np.ndarray:
        return self.nets.sampled[1]

    @property
    def template_index(self) -> np.ndarray | None:
        return self.nets.sampled[2]

    @property
    def source_index(self) -> np.ndarray | None:
        return self.nets.sampled[3]


def _search_scene(
    template: np.ndarray, source: np.ndarray, single: bool, scene: bool | SceneSearch | None
) -> SceneMatch | None:
    """The scene search's result for one pair (B = 1) where ``scene`` asks for it, else None.

    ``scene=None`` searches when :func:`~masknet.registration.stages.scene.is_scene`, and falls
    back to registering the clouds as they are where the search finds nothing to register
    (no region large enough, or under 3 scene points on the template); an explicit
    search raises MaskNetError there.
    """
    options = scene if isinstance(scene, SceneSearch) else SceneSearch()
    if scene is False or (scene is None and not single):
        return None
    if not single:
        raise MaskNetError("scene search takes one pair, not a batch")
    if scene is None and not is_scene(template[0], source[0], options):
        return None
    try:
        found = locate(template[0], source[0], options)
        if found.source_mask.sum() < MIN_POINTS:
            raise MaskNetError(
                f"scene search: {int(found.source_mask.sum())} scene points lie on the template "
                f"where it fits best; at least {MIN_POINTS} are needed to register"
            )
    except MaskNetError:
        if scene is None:
            return None
        raise
    return found


class CheckedClouds(NamedTuple):
    """The clouds as given, checked: template (B, N, 3) and source (B, M, 3) float64,
    single (one pair was given), and the input rows kept by ``drop_nonfinite`` (N0,) and
    (M0,) bool, or None."""

    template: np.ndarray
    source: np.ndarray
    single: bool
    template_rows: np.ndarray | None
    source_rows: np.ndarray | None


def check_clouds(template: Any, source: Any, plan: CallPlan) -> CheckedClouds:
    """Every check of the clouds, once (:func:`masknet.io_checks.check_cloud`), after
    dropping non-finite rows where the plan asks, and a warning where the two clouds look
    like different units (:mod:`masknet.registration.terms.units`); the later stages check
    nothing again."""
    template_rows = source_rows = None
    if plan.drop_nonfinite:
        template, source, template_rows, source_rows = finite_rows(template, source)
    clouds = CheckedClouds(*as_numpy_batch(template, source), template_rows, source_rows)
    for pair_template, pair_source in zip(clouds.template, clouds.source, strict=True):
        if warn_mixed_units(pair_template, pair_source).mixed:
            break  # one line for a batch
    return clouds


def enter_frame(
    clouds: CheckedClouds, plan: CallPlan, times: dict[str, float]
) -> tuple[FramedPair, CallPlan]:
    """The scene search in input units, the frame, the networks' sampled clouds; and the
    plan with its networks and its distances in frame units."""
    template, source, single = clouds.template, clouds.source, clouds.single
    found = _search_scene(template, source, single, plan.scene)
    scene = None
    if found is not None:  # the method registers the object's points, from the pose found
        scene = (found, source[0])
        source = transform_points(found.transform, source[0][found.source_mask])[None]
        plan = dataclasses.replace(plan, init="identity")  # a centroid shift would undo it
        if plan.method == "auto":  # the search is the global stage: Mask-ICP from its pose
            criteria = ICPCriteria(max_iterations=plan.max_iterations or 10)
            plan = dataclasses.replace(
                plan, method="icp", entry=METHOD_TABLE["icp"], options=criteria, scene_for_auto=True
            )
    plan = with_networks(plan)
    # Everything runs in one frame (the template's centroid, its RMS radius): the result
    # does not depend on the unit or the origin. Distances given in input units follow.
    frame = Frame.of(template, source)
    cut = getattr(plan.options, "max_correspondence_distance", None)
    if cut is not None:
        options = dataclasses.replace(plan.options, max_correspondence_distance=cut / frame.scale)
        plan = dataclasses.replace(plan, options=options)
    in_template, in_source = _template_in_frame(frame, template), frame.points_in(source)
    nets = NetworkClouds(in_template, in_source, single, plan.max_points, times)
    pair = FramedPair(
        frame,
        in_template,
        in_source,
        nets,
        single,
        template,
        clouds.template_rows,
        clouds.source_rows,
        scene,
    )
    return pair, plan


def _template_in_frame(frame: Frame, template: np.ndarray) -> np.ndarray:
    """``frame.points_in(template)`` (1, N, 3): from the call's prepared template where it is
    that template (:mod:`masknet.geometry.prepared_template`; the frame's centre, scale and
    rounding its key), so that the stages' views of it are prepared once."""
    prepared = active()
    if (
        prepared is None
        or template.shape[0] != 1
        or not np.array_equal(template[0], prepared.points)
    ):
        return frame.points_in(template)
    key = (frame.centre.tobytes(), frame.scale, frame.snap)
    return prepared.frame_points(key, lambda: frame.points_in(template))


def run_method(pair: FramedPair, plan: CallPlan, times: dict[str, float]) -> Solution:
    """The method: a pipeline on the full clouds (and its refined rounds), or the rounds
    of a back-end on the sampled ones."""
    single = pair.single
    if plan.entry.kind == "pipeline":  # full resolution; the networks see the sampled clouds
        models = MaskModels(plan.model, plan.search_model)
        found = adapter(plan.method)(
            pair.template, pair.source, pair.nets, models, plan.options, times, plan.precision
        )
        total, mask, source_mask, info = found.transform, found.mask, found.source_mask, found.info
        rounds = [total[0] if single else total]
        if plan.iterations > 1:  # refined Mask-ICP rounds from the pipeline's pose
            total, mask, source_mask, refined = _refined_rounds(
                pair.template, pair.source, total, plan, times
            )
            rounds += [r[0] if single else r for r in refined]
        return Solution(total, mask, source_mask, info, rounds)
    state = mask_and_register(
        pair.sampled_template,
        pair.sampled_source,
        plan.method,
        plan.model,
        plan.iterations,
        plan.options,
        times,
        k=plan.k,
        threshold=plan.threshold,
        precision=plan.precision,
        init=plan.init,
        refiner=plan.refiner,
    )
    return state._replace(rounds=[r[0] if single else r for r in state.rounds])


def _refined_rounds(
    template: np.ndarray,
    source: np.ndarray,
    start: np.ndarray,
    plan: CallPlan,
    times: dict[str, float],
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, list[np.ndarray]]:
    """A pipeline's pose (B, 4, 4) for template (B, N, 3) and source (B, M, 3) taken through
    ``iterations - 1`` refined Mask-ICP rounds, pair by pair (:func:`refine_pose`). Returns
    the transforms (B, 4, 4), the masks (B, N) and (B, M) or None, and the transform after
    each round."""
    rounds, poses = plan.iterations - 1, []
    for b in range(template.shape[0]):
        t, s = template[b], source[b]
        # The refiner sees the clouds at full resolution up to REFINE_POINTS: on real scans
        # its masks are more precise there than at the first round's size, spread.
        _, _, t_index, s_index = fit_to_network(t[None], s[None], True, REFINE_POINTS)
        sampled = (
            np.arange(len(t)) if t_index is None else t_index,
            np.arange(len(s)) if s_index is None else s_index,
        )
        spacing = median_spacing(t, sample=SPACING_SAMPLE) or 1.0
        cut = plan.options.cut(spacing)
        poses.append(refine_pose(t, s, sampled, start[b], plan.refiner, rounds, cut, times))
    transform = np.stack([p.transform for p in poses])
    history = [np.stack([p.rounds[r] for p in poses]) for r in range(rounds)]
    if plan.refiner is None:
        return transform, None, None, history
    masks = np.stack([p.mask for p in poses]), np.stack([p.source_mask for p in poses])
    return transform, *masks, history


def refine_plain(
    pair: FramedPair, found: Solution, plan: CallPlan, times: dict[str, float]
) -> Solution:
    """``refine_iterations`` of plain ICP on the whole (sampled) template from the pose
    found; the estimate unchanged when there are none."""
    if not plan.refine_iterations:
        return found
    tic = time.perf_counter()
    moved = transform_points(found.transform, pair.sampled_source)
    criteria = ICPCriteria(max_iterations=plan.refine_iterations)
    run = adapter("icp")(pair.sampled_template, moved, None, None, criteria)
    times["refine"] = time.perf_counter() - tic
    return found._replace(transform=run.transform @ found.transform)


def measure_fit(pair: FramedPair, found: Solution, plan: CallPlan) -> Solution:
    """Open3D's fitness and inlier RMSE of the pose returned, over every source point against
    the whole template, at the cut-off given or else 1.5 template spacings. A pipeline
    with one round reports its own fit (on its even subsets) and is left as it is; the
    rounds' own figure counted masked points at the sampled size (and with no cut-off
    every pair, always 1), and the networks report none."""
    if plan.entry.kind == "pipeline" and plan.iterations == 1:
        return found
    cut = getattr(plan.options, "max_correspondence_distance", None)
    fit = inlier_fit(pair.template, transform_points(found.transform, pair.source), cut)
    return found._replace(
        info={**found.info, "fitness": fit.fitness, "inlier_rmse": fit.inlier_rmse}
    )


def leave_frame(
    pair: FramedPair, found: Solution, plan: CallPlan, times: dict[str, float]
) -> RegistrationResult:
    """The result in input units: the transforms and report out of the frame, back to the
    whole scene after a search, and every mask spread once to every input row."""
    frame, single = pair.frame, pair.single
    total = frame.transforms_out(found.transform)
    rounds = [
        frame.transforms_out(r[None] if single else r)[0 if single else ...] for r in found.rounds
    ]
    info = _info_out(found.info, frame)
    mask, source_mask, inliers = found.mask, found.source_mask, found.inliers
    if plan.entry.kind != "pipeline":  # the sampled clouds' masks to every point
        mask, source_mask, inliers = _spread_sampled(pair, mask, source_mask, inliers)
    if pair.scene is not None:
        total, rounds, source_mask = _leave_scene(
            pair, plan, total, rounds, info, source_mask, times
        )
    if pair.template_rows is not None:  # dropped rows are neither inliers nor kept
        mask, inliers = (spread_rows(m, pair.template_rows) for m in (mask, inliers))
        source_mask = spread_rows(source_mask, pair.source_rows)

    def out(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else (a[0] if single else a)

    def info_out(a: np.ndarray) -> object:
        # A pair's text (info["path"]) is a plain str, as a reader compares and prints it.
        value = out(a)
        return str(value) if isinstance(value, np.str_) else value

    return RegistrationResult(
        R=out(total[:, :3, :3].copy()),
        t=out(total[:, :3, 3].copy()),
        transform=out(total),
        mask=out(mask),
        times=times,
        info={key: info_out(value) for key, value in info.items()},
        rounds=rounds,
        sampled=pair.nets.sizes() if single else None,
        correspondence_inliers=out(inliers),
        source_mask=out(source_mask),
        method=plan.method,
        scene=None if pair.scene is None else pair.scene[0],
    )


def _info_out(info: dict, frame: Frame) -> dict:
    """A method's report in input units: RMSEs scaled, the runner-up pose mapped out."""
    out = dict(info)
    if "inlier_rmse" in out:
        out["inlier_rmse"] = np.asarray(out["inlier_rmse"]) * frame.scale
    if "runner_up" in out:
        pose = np.asarray(out["runner_up"], dtype=np.float64)
        out["runner_up"] = np.where(np.isfinite(pose), frame.transforms_out(pose), np.nan)
    return out


def _spread_sampled(
    pair: FramedPair,
    mask: np.ndarray | None,
    source_mask: np.ndarray | None,
    inliers: np.ndarray | None,
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """Masks over the sampled clouds (1, N') and (1, M') spread to every point (each takes
    its nearest sampled point's label); correspondence inliers are not spread: points the
    network never saw are no inliers."""
    if pair.source_index is not None and source_mask is not None:
        source_mask = spread_mask(pair.source[0], pair.source_index, source_mask[0])[None]
    if pair.template_index is not None:
        if mask is not None:
            mask = spread_mask(pair.template[0], pair.template_index, mask[0])[None]
        if inliers is not None:
            full = np.zeros(pair.template.shape[:2], bool)
            full[:, pair.template_index] = inliers
            inliers = full
    return mask, source_mask, inliers


def _leave_scene(
    pair: FramedPair,
    plan: CallPlan,
    total: np.ndarray,
    rounds: list[np.ndarray],
    info: dict,
    source_mask: np.ndarray | None,
    times: dict[str, float],
) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """Back to the whole scene (1, 4, 4), then full-resolution ICP on the object's points
    from the method's pose and the search's (:func:`polish`); ``info`` gets the runner-up
    mapped back too. The source mask then covers the whole scene."""
    found, scene_source = pair.scene
    total = total @ found.transform
    tic = time.perf_counter()
    search_options = plan.scene if isinstance(plan.scene, SceneSearch) else None
    on_object = scene_source[found.source_mask]
    starts = [total[0], found.transform]
    total = polish(pair.template_input[0], on_object, starts, search_options)[None]
    times["refine"] += time.perf_counter() - tic
    rounds = [r @ found.transform for r in rounds]
    if "runner_up" in info:
        info["runner_up"] = info["runner_up"] @ found.transform
    kept = found.source_mask.copy()
    if source_mask is not None:
        kept[kept] = source_mask[0]
    if plan.scene_for_auto:
        info["path"] = np.array(["scene search"])
    times["search"] = found.seconds
    return total, rounds, kept[None]

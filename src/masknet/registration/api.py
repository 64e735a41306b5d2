"""``masknet.register``: one call for every registration method, with or without MaskNet.

``register(template, source, method=X)`` runs *Mask-X*: MaskNet predicts which
template points the partial source sees, and only those take part in X. With
``use_mask=False`` it is plain X, so X and Mask-X compare in one call.

One round is: (optionally) predict the mask for the source as it stands, move the
source by the initialisation (``init="centroid"``: its centroid onto the centroid
of the template points in use), run the method, compose. ``iterations=n`` repeats
rounds on the moved source: rounds >= 2 take their masks from a refiner that sees the
pair in one frame and start from the pose reached (``refine_masks="network"``: the
paper's loop, its MaskNet in every round); with the default method the first round
is the default pipeline's answer. ``refine_iterations`` ends with plain ICP against the
whole template from the estimate reached.

Clouds larger than ``max_points`` (single pairs) are brought to the network's
size by farthest point sampling, the source at the template's spacing (see
:mod:`masknet.geometry.sampling`); the transform applies to the full clouds, and
the returned mask covers every template point (each takes the label of its
nearest sampled point).
"""

from __future__ import annotations

import dataclasses
import functools
import time
from typing import Any

import numpy as np
import torch

from masknet.errors import MaskNetError, checks_done, warns_once
from masknet.geometry.clouds import MIN_POINTS, SPACING_SAMPLE, Frame, median_spacing
from masknet.geometry.sampling import spread_mask
from masknet.geometry.se3 import transform_points
from masknet.models import REGISTRATION_NETWORKS
from masknet.models.masknet import MaskNet
from masknet.models.two_sided import TwoSidedMaskNet
from masknet.registration.backends.base import MaskModels
from masknet.registration.evaluation import inlier_fit
from masknet.registration.methods import (
    GLOBAL_METHODS,
    INITS,
    METHOD_TABLE,
    METHOD_TITLES,
    METHODS,
    NETWORK_METHODS,
    adapter,
    default_method,
)
from masknet.registration.methods import (
    method_options as options_for,
)
from masknet.registration.options import ICPCriteria
from masknet.registration.refinement import (
    DEFAULT_REFINER,
    Refiner,
    refine_pose,
    resolve_refiner,
)
from masknet.registration.result import RegistrationResult
from masknet.registration.rounds import mask_and_register
from masknet.registration.sampling import fit_to_network
from masknet.registration.scene import SceneMatch, SceneSearch, is_scene, locate, polish
from masknet.registration.validation import (
    as_numpy_batch,
    check_arguments,
    finite_rows,
    spread_rows,
)
from masknet.runtime import small_blas

__all__ = [
    "GLOBAL_METHODS",
    "INITS",
    "METHODS",
    "METHOD_TITLES",
    "NETWORK_METHODS",
    "RegistrationResult",
    "register",
]


def _search_scene(
    template: np.ndarray, source: np.ndarray, single: bool, scene: bool | SceneSearch | None
) -> SceneMatch | None:
    """The scene search's result for one pair (B = 1) where ``scene`` asks for it, else None.

    ``scene=None`` searches when :func:`~masknet.registration.scene.is_scene`, and falls
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


@functools.lru_cache(maxsize=1)
def _default_model() -> MaskNet:
    """The shipped MaskNet weights, loaded once per process."""
    return MaskNet.pretrained()


@functools.lru_cache(maxsize=1)
def _default_two_sided() -> TwoSidedMaskNet:
    """The shipped two-sided MaskNet, the robust method's default, loaded once."""
    return TwoSidedMaskNet.pretrained()


@functools.cache
def _default_network(method: str) -> torch.nn.Module:
    """The shipped weights of a learned registration network, loaded once per process."""
    return REGISTRATION_NETWORKS[method].pretrained().eval()


def _info_out(info: dict, frame: Frame) -> dict:
    """A method's report in input units: RMSEs scaled, the runner-up pose mapped out."""
    out = dict(info)
    if "inlier_rmse" in out:
        out["inlier_rmse"] = np.asarray(out["inlier_rmse"]) * frame.scale
    if "runner_up" in out:
        pose = np.asarray(out["runner_up"], dtype=np.float64)
        out["runner_up"] = np.where(np.isfinite(pose), frame.transforms_out(pose), np.nan)
    return out


# Keywords that, with no method named, ask for Mask-ICP's rounds.
# The most points of each cloud the refiner sees in the rounds after a pipeline.
REFINE_POINTS = 4096
_ICP_FIELDS = tuple(f.name for f in dataclasses.fields(ICPCriteria))


@small_blas
@warns_once
def register(
    template: np.ndarray,
    source: np.ndarray,
    *,
    method: str | None = None,
    options: Any | None = None,
    use_mask: bool = True,
    iterations: int = 1,
    refine_iterations: int = 0,
    model: MaskNet | TwoSidedMaskNet | None = None,
    k: int | None = None,
    threshold: float | None = None,
    precision: str = "auto",
    init: str = "centroid",
    max_points: int = 1024,
    scene: bool | SceneSearch | None = None,
    refine_masks: str | Refiner | None = DEFAULT_REFINER,
    drop_nonfinite: bool = False,
    **method_options: Any,
) -> RegistrationResult:
    """Register a partial source to a full template, optionally through MaskNet's mask.

    Everything after the two clouds is keyword-only.

    Args:
        template: (N, 3) or (B, N, 3) full template cloud(s), any units.
        source: (M, 3) or (B, M, 3) partial source cloud(s), same units.
        method: a name of the method table (:data:`~masknet.registration.methods.METHOD_TABLE`).
            None (default) runs ``"auto"``, the method of a typed ``options`` object, or
            ``"icp"`` when an argument only Mask-ICP's rounds take is given
            (``k``, ``threshold``, ``refine_iterations``,
            ``init="identity"``, ICP's options). ``"auto"``: one round of Mask-ICP, its
            fit checked, and ``"robust"`` where the fit says it may be wrong
            (:mod:`masknet.registration.auto`; ``info["path"]`` says which ran).
            ``"robust"``: the coarse-to-fine search, FPFH correspondence hypotheses, then
            the two-sided mask and rotation hypotheses, one score, refinement
            (:mod:`masknet.registration.coarse`; any rotation, outliers in the source;
            ``info["ambiguous"]`` and ``info["runner_up"]`` when another pose fits as
            well). ``"icp"`` (the paper's Mask-ICP: a KD-tree loop for one pair, batched
            torch ICP for a batch), ``"open3d-icp"`` (Open3D's point-to-point ICP, pair by
            pair), a learned network: ``"pointnetlk"``, ``"dcp"``, ``"prnet"``,
            ``"pcrnet"`` or ``"rpmnet"`` (the shipped weights unless ``network=`` is
            given), ``"open3d-ransac"`` or ``"open3d-fgr"`` (Open3D's global registration
            on FPFH features). ``"auto"`` and ``"robust"`` run whole pipelines: they ignore
            ``k``, ``threshold`` and ``init``, and refuse ``refine_iterations``; with
            ``iterations`` > 1 their answer is round 1 and refined rounds follow.
        options: the method's typed options (:mod:`masknet.registration.options`):
            ``ICPCriteria`` (``"icp"``), ``Open3DICPOptions``, ``PointNetLKOptions``,
            ``NetworkOptions`` (DCP, PRNet, PCRNet, RPM-Net), ``RANSACOptions``,
            ``FGROptions``, ``RobustOptions`` (``"auto"``, ``"robust"``). Or give its
            fields as keywords (``**method_options``), not both.
        use_mask: Mask-X (True) or plain X (False).
        iterations: rounds of {mask -> initialise -> register -> move the source}. After
            ``"auto"`` (the default) or ``"robust"``, whose answer is round 1, each further
            round masks both clouds with the refiner at the pose reached (seeing up to
            ``REFINE_POINTS`` of each) and runs ICP at full resolution on the masked points,
            pairs cut at the pipeline's ``max_correspondence_distance``; ``mask`` and
            ``source_mask`` are the refiner's at the pose returned.
        refine_iterations: after the rounds, this many iterations of plain ICP
            against the whole template (0: none).
        model: the MaskNet of the first round; None loads shipped weights once: the
            paper's ``masknet_modelnet40`` for one round (and ``"auto"``'s fast path;
            its escalation uses ``masknet2_scans``), the two-sided ``masknet2_scans`` for
            ``iterations`` > 1 and ``"robust"``. A
            :class:`~masknet.models.two_sided.TwoSidedMaskNet` masks both clouds: the
            method then sees only the source points it keeps. Any object with
            ``predict_masks(template, source, *, k, threshold, precision) -> (template_mask,
            source_mask or None)`` serves (masks given in advance, another network).
        k, threshold: inlier selection, as :meth:`MaskNet.predict_mask` (default
            top-k with k = M); only with ``use_mask=True``.
        precision: MaskNet's inference precision, as :meth:`MaskNet.predict`
            (``"auto"``: bf16 where the hardware runs it natively).
        init: ``"centroid"`` (default: translate the centroid of the source points in use
            onto the centroid of the template points in use, i.e. the masked ones for
            Mask-X) or ``"identity"``. PointNetLK centres both clouds itself either way.
        max_points: single pairs larger than this are subsampled for the method
            (farthest point sampling); batches must already fit.
        scene: find the template, a small object, in a large source scan first
            (:func:`masknet.registration.scene.locate`): True, False, or
            :class:`~masknet.registration.scene.SceneSearch` options (implies True).
            None (default) searches single pairs whose source is at least 3 times as
            spread out as the template (median distance of the points from their median
            point), and registers the clouds as they are where the search finds nothing.
            The method then runs on the scene points found on the object, from the pose
            found (``init`` is then ``"identity"``), and full-resolution ICP on those
            points from the method's pose and from the search's ends the call, the
            better fit winning (:func:`~masknet.registration.scene.polish`).
            ``source_mask`` marks the points found and ``result.scene`` holds the
            search's :class:`~masknet.registration.scene.SceneMatch`; ``info``'s
            ``fitness`` and ``inlier_rmse`` are still the method's, before the polish.
        refine_masks: the masks of rounds >= 2 (``iterations`` > 1, with a mask), taken
            on the pair as the previous round left it, in one frame
            (:mod:`masknet.registration.refinement`): ``"learned"`` (default, the
            shipped :class:`~masknet.models.refine.RefineMaskNet`), ``"nearest"`` (the
            nearest-neighbour rule, about twice as fast), an object with
            ``predict_masks(template, source)``, or ``"network"`` / None: ``model``
            again in every round, each cloud centred on its own centroid (the paper's
            loop; after a pipeline: plain ICP rounds, no mask). Refined rounds mask the
            source too (``source_mask``) and start from the pose reached. A refiner's template mask is the top k points with k the
            number of source points it keeps, and the learned one runs in fp32: ``k``,
            ``threshold`` and ``precision`` apply to round 1.
        drop_nonfinite: drop template and source rows holding NaN or inf (one pair
            only) instead of refusing them, as ``masknet register --drop-nonfinite``;
            ``mask`` and ``source_mask`` still cover every input row, False where dropped.
        **method_options: the fields of the method's options class, spelled inline
            (``register(a, b, method="icp", max_iterations=30)``). Distances
            (``max_correspondence_distance``) are in the clouds' units.

    Returns:
        RegistrationResult (source -> template, see :mod:`masknet.geometry.se3`).

    Raises:
        MaskNetError: bad clouds (shape, batch sizes, or what
            :func:`masknet.io_checks.check_cloud` refuses: NaN/inf, fewer than 3 points,
            a transposed array, identical or collinear points, overflowing coordinates),
            an unknown method, option or init, bad iterations/k/threshold or option
            values, or (for the Open3D methods) no Open3D.
    """
    start = time.perf_counter()
    method = default_method(
        method,
        options,
        {
            "k": k is not None,
            "threshold": threshold is not None,
            "refine_iterations": refine_iterations != 0,
            "init": init != "centroid",
            "icp options": any(f in method_options for f in _ICP_FIELDS),
        },
    )
    check_arguments(method, iterations, k, threshold, use_mask, init, refine_iterations, max_points)
    if model is not None and not hasattr(model, "predict_masks"):
        raise MaskNetError(
            f"model must be a mask network, got {type(model).__name__} {model!r:.60}; "
            "load a file with MaskNet.from_file(path) (TwoSidedMaskNet.from_file for "
            "two-sided weights)"
        )
    entry = METHOD_TABLE[method]
    if entry.kind == "pipeline" and refine_iterations:
        raise MaskNetError(
            f"refine_iterations is for the rounds' methods; {method!r} refines itself "
            "(ICP with a pair cut-off on the source points it keeps)"
        )
    opts = options_for(method, options, method_options)
    template_rows = source_rows = None
    if drop_nonfinite:
        template, source, template_rows, source_rows = finite_rows(template, source)
    tpl_full, src_full, single = as_numpy_batch(template, source)
    # Checked once, here: the stages (the networks check clouds given to them) do not
    # check or warn again.
    with checks_done():
        found = _search_scene(tpl_full, src_full, single, scene)
        auto_scene = found is not None and method == "auto"
        if found is not None:  # the method registers the object's points, from the pose found
            scene_source = src_full[0]
            src_full = transform_points(found.transform, scene_source[found.source_mask])[None]
            init = "identity"  # the search placed them: a centroid shift would undo that
            if method == "auto":  # the search is the global stage: Mask-ICP from its pose
                method, entry = "icp", METHOD_TABLE["icp"]
                opts = ICPCriteria(max_iterations=method_options.get("max_iterations", 10))
        # A loop and robust mask with the two-sided network by default (it rejects outliers).
        two_sided_default = method == "robust" or (iterations > 1 and entry.kind != "pipeline")
        search_model = None  # auto's escalation: the two-sided network masks both clouds
        if use_mask and method == "auto":
            search_model = model if isinstance(model, TwoSidedMaskNet) else _default_two_sided()
        if use_mask and model is None:
            # One round is the paper's Mask-X (auto's fast path too: with the two-sided
            # network there, fewer clean pairs pass the check and it is slower; with it given
            # as model=, the escalation reuses its masks). A loop starts from the two-sided
            # network, which also rejects source outliers; its clean-pair cost after one round
            # is recovered by the refined rounds (docs/RESULTS.md, masks per round).
            model = _default_two_sided() if two_sided_default else _default_model()
        # Refined rounds exist only in a loop (robust and auto refine by ICP with a cut-off).
        refiner = resolve_refiner(refine_masks, model if use_mask and iterations > 1 else None)
        if entry.kind == "network" and opts.network is None:
            opts = dataclasses.replace(opts, network=_default_network(method))

        # Everything runs in one frame (the template's centroid, its RMS radius): the result
        # does not depend on the unit or the origin. Distances given in input units follow.
        frame, tpl_input = Frame.of(tpl_full, src_full), tpl_full
        tpl_full, src_full = frame.points_in(tpl_full), frame.points_in(src_full)
        if getattr(opts, "max_correspondence_distance", None) is not None:
            opts = dataclasses.replace(
                opts, max_correspondence_distance=opts.max_correspondence_distance / frame.scale
            )
        times = {"sample": 0.0, "mask": 0.0, "register": 0.0, "refine": 0.0}
        tic = time.perf_counter()
        tpl, src, template_index, source_index = fit_to_network(
            tpl_full, src_full, single, max_points
        )
        times["sample"] = time.perf_counter() - tic

        if entry.kind == "pipeline":  # full resolution; the networks see the sampled clouds
            models = MaskModels(model if use_mask else None, search_model)
            run = adapter(method)(tpl_full, src_full, tpl, src, models, opts, times, precision)
            total, mask, source_mask, info = run
            inliers, rounds = None, [total[0] if single else total]
            if iterations > 1:  # refined Mask-ICP rounds from the pipeline's pose
                total, mask, source_mask, refined = _refined_rounds(
                    tpl_full,
                    src_full,
                    total,
                    refiner,
                    iterations - 1,
                    opts,
                    times,
                )
                rounds += [r[0] if single else r for r in refined]
            template_index = source_index = None  # the masks cover the full clouds already
        else:
            state = mask_and_register(
                tpl,
                src,
                method,
                model if use_mask else None,
                iterations,
                opts,
                times,
                k=k,
                threshold=threshold,
                precision=precision,
                init=init,
                refiner=refiner,
            )
            total, mask, source_mask = state.transform, state.mask, state.source_mask
            info, inliers = state.run.info, state.run.correspondence_inliers
            rounds = [r[0] if single else r for r in state.rounds]
        if refine_iterations:
            tic = time.perf_counter()
            moved = transform_points(total, src)
            run = adapter("icp")(
                tpl, moved, None, None, ICPCriteria(max_iterations=refine_iterations)
            )
            total = run.transform @ total
            times["refine"] = time.perf_counter() - tic
        if entry.kind != "pipeline" or iterations > 1:
            # Open3D's fitness of the pose returned, over every source point against the
            # whole template, at the cut-off given or else 1.5 template spacings: the
            # rounds' own figure counted masked points at the sampled size (and with no
            # cut-off every pair, always 1), and the networks report none.
            cut = getattr(opts, "max_correspondence_distance", None)
            fit = inlier_fit(tpl_full, transform_points(total, src_full), cut)
            info = {**info, "fitness": fit.fitness, "inlier_rmse": fit.inlier_rmse}

        total = frame.transforms_out(total)
        rounds = [
            frame.transforms_out(r[None] if single else r)[0 if single else ...] for r in rounds
        ]
        info = _info_out(info, frame)
        if source_index is not None and source_mask is not None:
            source_mask = spread_mask(src_full[0], source_index, source_mask[0])[None]
        if found is not None:  # back to the whole scene, then full-resolution ICP on the object
            total = total @ found.transform
            tic = time.perf_counter()
            search_options = scene if isinstance(scene, SceneSearch) else None
            on_object = scene_source[found.source_mask]
            total = polish(tpl_input[0], on_object, [total[0], found.transform], search_options)[
                None
            ]
            times["refine"] += time.perf_counter() - tic
            rounds = [r @ found.transform for r in rounds]
            if "runner_up" in info:  # also back to the whole scene
                info["runner_up"] = info["runner_up"] @ found.transform
            on_object = found.source_mask.copy()
            if source_mask is not None:
                on_object[on_object] = source_mask[0]
            source_mask = on_object[None]
            if auto_scene:
                info["path"] = np.array(["scene search"])
            times["search"] = found.seconds
        if template_index is not None:
            if mask is not None:
                mask = spread_mask(tpl_full[0], template_index, mask[0])[None]
            if inliers is not None:  # points the network never saw are not inliers
                full = np.zeros(tpl_full.shape[:2], bool)
                full[:, template_index] = inliers
                inliers = full

        if template_rows is not None:  # dropped rows are neither inliers nor kept
            mask, inliers = (spread_rows(m, template_rows) for m in (mask, inliers))
            source_mask = spread_rows(source_mask, source_rows)

        def out(a: np.ndarray) -> np.ndarray:
            return a[0] if single else a

        times["total"] = time.perf_counter() - start
        return RegistrationResult(
            R=out(total[:, :3, :3].copy()),
            t=out(total[:, :3, 3].copy()),
            transform=out(total),
            mask=None if mask is None else out(mask),
            times=times,
            info={key: out(value) for key, value in info.items()},
            rounds=rounds,
            sampled=(tpl.shape[1], src.shape[1]) if single else None,
            correspondence_inliers=None if inliers is None else out(inliers),
            source_mask=None if source_mask is None else out(source_mask),
            method=method,
            scene=found,
        )


def _refined_rounds(
    template: np.ndarray,
    source: np.ndarray,
    start: np.ndarray,
    refiner: Refiner | None,
    rounds: int,
    options: Any,
    times: dict[str, float],
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, list[np.ndarray]]:
    """A pipeline's pose (B, 4, 4) for template (B, N, 3) and source (B, M, 3) taken through
    ``rounds`` refined Mask-ICP rounds, pair by pair (:func:`refine_pose`). Returns the transforms (B, 4, 4), the
    masks (B, N) and (B, M) or None, and the transform after each round."""
    poses = []
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
        poses.append(
            refine_pose(t, s, sampled, start[b], refiner, rounds, options.cut(spacing), times)
        )
    transform = np.stack([p.transform for p in poses])
    history = [np.stack([p.rounds[r] for p in poses]) for r in range(rounds)]
    if refiner is None:
        return transform, None, None, history
    return (
        transform,
        np.stack([p.mask for p in poses]),
        np.stack([p.source_mask for p in poses]),
        history,
    )

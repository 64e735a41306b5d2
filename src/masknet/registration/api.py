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

import time
from typing import Any

import numpy as np

from masknet._moved import moved_names
from masknet.errors import checks_done, warn, warns_once
from masknet.geometry.prepared_template import PreparedTemplate, prepare_template, using
from masknet.geometry.se3 import transform_points
from masknet.models.masknet import MaskNet
from masknet.models.two_sided import TwoSidedMaskNet
from masknet.registration.pipeline import (
    check_clouds,
    enter_frame,
    leave_frame,
    measure_fit,
    refine_plain,
    run_method,
)
from masknet.registration.plan import plan_call
from masknet.registration.stages.refinement import DEFAULT_REFINER, Refiner
from masknet.registration.stages.scene import SceneSearch
from masknet.registration.terms.methods import (
    GLOBAL_METHODS,
    INITS,
    METHOD_TITLES,
    METHODS,
    NETWORK_METHODS,
    check_pipeline_keywords,
    default_method,
    open3d_spelling,
)
from masknet.registration.terms.methods import (
    method_options as options_for,
)
from masknet.registration.terms.result import RegistrationResult
from masknet.registration.terms.validation import (
    as_rigid_transforms,
    check_arguments,
    mask_threshold_of,
    split_init,
)
from masknet.runtime import small_blas

__all__ = [
    "GLOBAL_METHODS",
    "INITS",
    "METHODS",
    "METHOD_TITLES",
    "NETWORK_METHODS",
    "PreparedTemplate",
    "RegistrationResult",
    "prepare_template",
    "register",
]


@small_blas
@warns_once
def register(
    template: np.ndarray | PreparedTemplate,
    source: np.ndarray,
    *,
    method: str | None = None,
    options: Any | None = None,
    use_mask: bool = True,
    iterations: int = 1,
    refine_iterations: int = 0,
    model: MaskNet | TwoSidedMaskNet | None = None,
    k: int | None = None,
    mask_threshold: float | None = None,
    precision: str = "auto",
    init: str | np.ndarray | None = "centroid",
    max_points: int = 1024,
    scene: bool | SceneSearch | None = None,
    refine_masks: str | Refiner | None = DEFAULT_REFINER,
    drop_nonfinite: bool = False,
    threshold: float | None = None,
    **method_options: Any,
) -> RegistrationResult:
    """Register a partial source to a full template, optionally through MaskNet's mask.

    Everything after the two clouds is keyword-only.

    Args:
        template: (N, 3) or (B, N, 3) full template cloud(s), any units; or a
            :class:`~masknet.geometry.prepared_template.PreparedTemplate`
            (:func:`prepare_template`), whose template-only views (its frame, network
            sample and encoding, fit and verdict subsets, trees, shape measure) are
            computed once and reused by every call given it, the results unchanged.
        source: (M, 3) or (B, M, 3) partial source cloud(s), same units.
        method: a name of the method table (:data:`~masknet.registration.terms.methods.METHOD_TABLE`).
            None (default) runs ``"auto"``, or the method of a typed ``options`` object; no
            other argument changes it. An argument that the pipelines do not take as the
            rounds' methods do (``k``, ``mask_threshold``, ``refine_iterations``, Open3D's
            ``max_iteration``, ``max_iterations`` with no method named, ICP's other options)
            is refused in one line naming the method that takes it
            (:func:`~masknet.registration.terms.methods.check_pipeline_keywords`);
            ``max_correspondence_distance`` and ``init`` tune the pipeline.
            ``"auto"``: on objects one round of
            Mask-ICP, its fit checked; on scans and sparse clouds the consensus front end
            first; ``"robust"`` where these do not settle the pair
            (:mod:`masknet.registration.stages.auto`; ``info["path"]`` says which ran).
            ``"robust"``: the coarse-to-fine search, FPFH correspondence hypotheses, then
            the two-sided mask and rotation hypotheses, one score, refinement
            (:mod:`masknet.registration.stages.search`; any rotation, outliers in the source;
            ``info["ambiguous"]`` and ``info["runner_up"]`` when another pose fits as
            well). ``"icp"`` (the paper's Mask-ICP: a KD-tree loop for one pair, batched
            torch ICP for a batch), ``"open3d-icp"`` (Open3D's point-to-point ICP, pair by
            pair), a learned network: ``"pointnetlk"``, ``"dcp"``, ``"prnet"``,
            ``"pcrnet"`` or ``"rpmnet"`` (the shipped weights unless ``network=`` is
            given), ``"open3d-ransac"`` or ``"open3d-fgr"`` (Open3D's global registration
            on FPFH features). ``"auto"`` and ``"robust"`` run whole pipelines: they refuse
            ``k``, ``mask_threshold`` and ``refine_iterations``, search from the source as
            given (moved by an ``init`` matrix), and cut ICP's pairs at
            ``max_correspondence_distance``; with ``iterations`` > 1 their answer is round 1
            and refined rounds follow.
        options: the method's typed options (:mod:`masknet.registration.terms.options`):
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
        model: the MaskNet of the first round; None loads shipped weights once: for one
            round of ``"icp"`` or a learned network the CrossMaskNet
            ``crossmasknet_modelnet40`` (``plan.MASK_X_METHODS``; for Open3D's methods the
            paper's ``masknet_modelnet40``, which
            ``model=MaskNet.pretrained()`` gives for any method; ``"auto"``'s fast path the
            smaller ``masknet_modelnet40_small``; its escalation uses ``masknet2_scans``),
            the two-sided ``masknet2_scans`` for
            ``iterations`` > 1 and ``"robust"``. A
            :class:`~masknet.models.two_sided.TwoSidedMaskNet` masks both clouds: the
            method then sees only the source points it keeps. Any object with
            ``predict_masks(template, source, *, k, threshold, precision) -> (template_mask,
            source_mask or None)`` serves (masks given in advance, another network).
        k, mask_threshold: round 1's inlier selection, as :meth:`MaskNet.predict_mask`'s
            ``k`` and ``threshold`` (default top-k with k = M); only with ``use_mask=True``,
            for the rounds' methods.
        precision: MaskNet's inference precision, as :meth:`MaskNet.predict`
            (``"auto"``: bf16 where the hardware runs it natively).
        init: ``"centroid"`` (default: translate the centroid of the source points in use
            onto the centroid of the template points in use, i.e. the masked ones for
            Mask-X) or ``"identity"`` (None: the default). PointNetLK centres both clouds
            itself either way.
            Or Open3D's ``init``: a (4, 4) or (B, 4, 4) source -> template transform to
            start from, for every method. The source is moved by it, the method runs as
            with ``"identity"`` (the pipelines, which search globally, include it as the
            pose as given), and every returned pose is composed with it, so
            ``result.transform`` maps the source as given. ``np.eye(4)`` is the same start
            as ``"identity"``; the pipelines start from the source as given whatever its
            name (a matrix moves it first).
        max_points: single pairs larger than this are subsampled for the method
            (farthest point sampling); batches must already fit.
        scene: find the template, a small object, in a large source scan first
            (:func:`masknet.registration.stages.scene.locate`): True, False, or
            :class:`~masknet.registration.stages.scene.SceneSearch` options (implies True).
            None (default) searches single pairs whose source is at least 3 times as
            spread out as the template (median distance of the points from their median
            point), and registers the clouds as they are where the search finds nothing.
            The method then runs on the scene points found on the object, from the pose
            found (``init`` is then ``"identity"``), and full-resolution ICP on those
            points from the method's pose and from the search's ends the call, the
            better fit winning (:func:`~masknet.registration.stages.scene.polish`).
            ``source_mask`` marks the points found and ``result.scene`` holds the
            search's :class:`~masknet.registration.stages.scene.SceneMatch`; ``info``'s
            ``fitness`` and ``inlier_rmse`` are still the method's, before the polish.
        refine_masks: the masks of rounds >= 2 (``iterations`` > 1, with a mask), taken
            on the pair as the previous round left it, in one frame
            (:mod:`masknet.registration.stages.refinement`): ``"learned"`` (default, the
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
        threshold: deprecated name of ``mask_threshold`` (DeprecationWarning): Open3D's
            ``threshold`` is the pair cut-off, ``max_correspondence_distance`` here.
        **method_options: the fields of the method's options class, spelled inline
            (``register(a, b, method="icp", max_iterations=30)``); Open3D's
            ``max_iteration`` is taken as ``max_iterations`` by the rounds' methods (ICP's
            iteration cap; the pipelines refuse it). Distances
            (``max_correspondence_distance``) are in the clouds' units.

    Returns:
        RegistrationResult (source -> template, see :mod:`masknet.geometry.se3`).

    Raises:
        MaskNetError: bad clouds (shape, batch sizes, or what
            :func:`masknet.io_checks.check_cloud` refuses: NaN/inf, fewer than 3 points,
            a transposed array, identical or collinear points, overflowing coordinates),
            an unknown method, option or init, a keyword the method does not take, bad
            iterations/k/mask_threshold or option
            values, or (for the Open3D methods) no Open3D.
    """
    start = time.perf_counter()
    prepared = template if isinstance(template, PreparedTemplate) else None
    if prepared is not None:
        template = prepared.points
    cut_off = {"threshold": threshold, "mask_threshold": mask_threshold}  # as spelled
    threshold = mask_threshold_of(mask_threshold, threshold)
    named, method = method is not None, default_method(method, options)
    check_arguments(method, iterations, k, threshold, use_mask, init, refine_iterations, max_points)
    given = [n for n, v in (("k", k), *cut_off.items()) if v is not None]
    check_pipeline_keywords(method, named, given + list(method_options))
    method_options = open3d_spelling(method_options)  # max_iteration: Open3D's name
    init, start_pose = split_init(init)
    plan = plan_call(
        method,
        options_for(method, options, method_options),
        model,
        use_mask=use_mask,
        iterations=iterations,
        refine_iterations=refine_iterations,
        k=k,
        threshold=threshold,
        precision=precision,
        init=init,
        max_points=max_points,
        scene=scene,
        refine_masks=refine_masks,
        drop_nonfinite=drop_nonfinite,
        max_iterations=method_options.get("max_iterations"),
    )
    times = {"sample": 0.0, "mask": 0.0, "register": 0.0, "refine": 0.0}
    clouds = check_clouds(template, source, plan)
    if start_pose is not None:  # Open3D's init: the method starts from the source moved by it
        start_pose = as_rigid_transforms(start_pose, clouds.source.shape[0])
        clouds = clouds._replace(source=transform_points(start_pose, clouds.source))
    # Checked once, here: the stages (the networks check clouds given to them) do not
    # check or warn again.
    with checks_done(), using(prepared):
        pair, plan = enter_frame(clouds, plan, times)
        found = run_method(pair, plan, times)
        found = refine_plain(pair, found, plan, times)
        found = measure_fit(pair, found, plan)
        result = leave_frame(pair, found, plan, times)
    if start_pose is not None:
        result = result.started_from(start_pose)
    _say_unused_cut(plan, result)
    times["total"] = time.perf_counter() - start
    return result


def _say_unused_cut(plan: Any, result: RegistrationResult) -> None:
    """Warn where a given ``max_correspondence_distance`` cut no pair: ``"auto"``'s
    consensus front end refines at its own cuts, in voxels, and it ended the call."""
    paths = np.atleast_1d(result.info.get("path", []))
    cut = getattr(plan.options, "max_correspondence_distance", None)
    if plan.method == "auto" and cut is not None and any("consensus" in p for p in paths):
        warn(
            "max_correspondence_distance was not used: the consensus front end ended the "
            "call, refining at its own cuts (consensus_points=0 turns it off)",
            stacklevel=6,  # register's caller, past the decorators
        )


# Moved to the stages of a call.
__getattr__ = moved_names(__name__, {"REFINE_POINTS": "masknet.registration.pipeline"})

"""The plan of one :func:`masknet.register` call: what it resolved from its arguments (the
method, its checked options, the networks it masks with), before it touches the clouds."""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import torch

from masknet.errors import MaskNetError
from masknet.models import REGISTRATION_NETWORKS
from masknet.models.cross_masknet import CrossMaskNet
from masknet.models.masknet import MaskNet
from masknet.models.two_sided import TwoSidedMaskNet
from masknet.registration.stages.refinement import Refiner, resolve_refiner
from masknet.registration.stages.scene import SceneSearch
from masknet.registration.terms.methods import METHOD_TABLE, NETWORK_METHODS, Method

__all__ = [
    "MASK_X_METHODS",
    "MASK_X_WEIGHTS",
    "CallPlan",
    "default_fast_model",
    "default_mask_x_model",
    "default_model",
    "default_network",
    "default_two_sided",
    "plan_call",
    "with_networks",
]


@functools.lru_cache(maxsize=1)
def default_model() -> MaskNet:
    """The shipped MaskNet weights, loaded once per process."""
    return MaskNet.pretrained()


# The mask network of "auto"'s fast path. Its mask only starts Mask-ICP (an accepted
# result's mask is the template points the moved source covers), and there the small
# network registers as well as the paper's: on the robust benchmark's sets, seed 0, means
# within 0.2 degrees but for one symmetric shape at rotations to 180 degrees (148 degrees
# off, accepted at a fit of 0.990), and on seeds 1-3 as well or better, in 1.5-2.6 times
# less time a call in fp32 (docs/RESULTS.md, robust). Not after a scene search: there the
# object is cut from a scene, and on the synthetic scenes the small network's Mask-ICP
# found 38 of 60 objects against the paper's 40.
FAST_PATH_WEIGHTS = "modelnet40_small"


@functools.lru_cache(maxsize=1)
def default_fast_model() -> MaskNet:
    """The shipped small MaskNet (``FAST_PATH_WEIGHTS``), ``"auto"``'s default, loaded once."""
    return MaskNet.pretrained(FAST_PATH_WEIGHTS)


# One round of Mask-X with these methods masks with the shipped CrossMaskNet
# (``crossmasknet_modelnet40``, more precise than the paper's MaskNet on the ModelNet40 test
# pairs: its model card). ``model=MaskNet.pretrained()`` (``--weights modelnet40``) gives the
# paper's network. The other methods (Open3D's) keep the paper's.
MASK_X_METHODS = ("icp", *NETWORK_METHODS)
MASK_X_WEIGHTS = "modelnet40"


@functools.lru_cache(maxsize=1)
def default_mask_x_model() -> CrossMaskNet:
    """The mask of one round of Mask-X (:data:`MASK_X_METHODS`), loaded once: the shipped
    CrossMaskNet. Its FPFH inputs come from Open3D where it imports, else from the same
    computation in numpy (:mod:`masknet.geometry.fpfh`)."""
    return CrossMaskNet.pretrained(MASK_X_WEIGHTS)


@functools.lru_cache(maxsize=1)
def default_two_sided() -> TwoSidedMaskNet:
    """The shipped two-sided MaskNet, the robust method's default, loaded once."""
    return TwoSidedMaskNet.pretrained()


@functools.cache
def default_network(method: str) -> torch.nn.Module:
    """The shipped weights of a learned registration network, loaded once per process."""
    return REGISTRATION_NETWORKS[method].pretrained().eval()


@dataclasses.dataclass(frozen=True)
class CallPlan:
    """What a call resolved from its arguments, before it touches the clouds.

    ``model`` is the mask network of round 1 (None: no mask), ``search_model`` the
    two-sided network of ``"auto"``'s escalation, ``refiner`` the masks of rounds >= 2.
    ``model``, ``search_model`` and ``refiner`` are filled in by :func:`enter_frame`,
    once the scene search has said which method runs. Distances in ``options`` are in
    input units here and in frame units after :func:`enter_frame`."""

    method: str
    entry: Method
    options: Any
    use_mask: bool
    iterations: int
    refine_iterations: int
    k: int | None
    threshold: float | None
    precision: str
    init: str
    max_points: int
    scene: bool | SceneSearch | None
    refine_masks: Any
    drop_nonfinite: bool
    max_iterations: int | None = None  # given by the caller (the scene's Mask-ICP uses it)
    scene_for_auto: bool = False  # "auto" found the object by the scene search
    model: Any = None
    search_model: Any = None
    refiner: Refiner | None = None


def plan_call(method: str, options: Any, model: Any, **arguments: Any) -> CallPlan:
    """The :class:`CallPlan` of checked arguments; refuses what no stage could run."""
    if model is not None and not hasattr(model, "predict_masks"):
        raise MaskNetError(
            f"model must be a mask network, got {type(model).__name__} {model!r:.60}; "
            "load a file with MaskNet.from_file(path) (TwoSidedMaskNet.from_file for "
            "two-sided weights)"
        )
    entry = METHOD_TABLE[method]
    if entry.kind == "pipeline" and arguments["refine_iterations"]:
        raise MaskNetError(
            f"refine_iterations is for the rounds' methods; {method!r} refines itself "
            '(ICP with a pair cut-off on the source points it keeps): pass method="icp" '
            "(--method icp) to use it"
        )
    return CallPlan(method, entry, options, model=model, **arguments)


def with_networks(plan: CallPlan) -> CallPlan:
    """The plan with its default networks loaded where the caller gave none (after the scene
    search, which may change the method)."""
    # A loop and robust mask with the two-sided network by default (it rejects outliers).
    two_sided = plan.method == "robust" or (plan.iterations > 1 and plan.entry.kind != "pipeline")
    model, search_model = plan.model, None
    if plan.use_mask and plan.method == "auto":  # auto's escalation masks both clouds
        search_model = model if isinstance(model, TwoSidedMaskNet) else default_two_sided()
    if plan.use_mask and model is None:
        # One round of Mask-X masks with CrossMaskNet (MASK_X_METHODS); auto's fast path masks
        # with the small one (FAST_PATH_WEIGHTS; with the two-sided network there, fewer
        # clean pairs pass the check and it is slower). A loop starts from the two-sided
        # network, which also rejects source outliers; its clean-pair cost after one round
        # is recovered by the refined rounds (docs/RESULTS.md, masks per round).
        if two_sided:
            model = default_two_sided()
        elif plan.method == "auto":  # after a scene search the method is "icp" by now
            model = default_fast_model()
        elif plan.method in MASK_X_METHODS and not plan.scene_for_auto:
            model = default_mask_x_model()
        else:
            model = default_model()
    # Refined rounds exist only in a loop (robust and auto refine by ICP with a cut-off).
    in_loop = model if plan.use_mask and plan.iterations > 1 else None
    options = plan.options
    if plan.entry.kind == "network" and options.network is None:
        options = dataclasses.replace(options, network=default_network(plan.method))
    return dataclasses.replace(
        plan,
        model=model if plan.use_mask else None,
        search_model=search_model,
        refiner=resolve_refiner(plan.refine_masks, in_loop),
        options=options,
    )

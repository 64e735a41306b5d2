"""masknet.registration.plan: what a call resolves before it touches the clouds, and the
default networks it loads once."""

from __future__ import annotations

import pytest

from masknet import MaskNetError
from masknet.models import MaskNet
from masknet.models.two_sided import TwoSidedMaskNet
from masknet.registration.plan import (
    FAST_PATH_WEIGHTS,
    default_fast_model,
    default_model,
    default_two_sided,
    plan_call,
    with_networks,
)
from masknet.registration.terms.options import ICPCriteria, RobustOptions

ARGUMENTS = dict(
    use_mask=True, iterations=1, refine_iterations=0, k=None, threshold=None, precision="fp32",
    init="centroid", max_points=1024, scene=None, refine_masks="learned", drop_nonfinite=False,
)  # fmt: skip


def test_the_default_networks_load_once():
    assert default_model() is default_model() and isinstance(default_model(), MaskNet)
    assert default_two_sided() is default_two_sided()
    assert isinstance(default_two_sided(), TwoSidedMaskNet)
    assert default_fast_model() is default_fast_model()
    # The fast path's network is the small one: fewer parameters than the paper's.
    small, paper = default_fast_model(), default_model()
    assert FAST_PATH_WEIGHTS == "modelnet40_small"
    assert (
        sum(p.numel() for p in small.parameters()) < sum(p.numel() for p in paper.parameters()) / 5
    )


def test_which_networks_a_plan_gets():
    one_round = with_networks(plan_call("icp", ICPCriteria(), None, **ARGUMENTS))
    assert one_round.model is default_model() and one_round.refiner is None
    auto = with_networks(plan_call("auto", RobustOptions(), None, **ARGUMENTS))
    assert auto.model is default_fast_model() and auto.search_model is default_two_sided()
    given = MaskNet.pretrained()
    assert with_networks(plan_call("auto", RobustOptions(), given, **ARGUMENTS)).model is given
    loop = with_networks(plan_call("icp", ICPCriteria(), None, **{**ARGUMENTS, "iterations": 3}))
    assert loop.model is default_two_sided() and loop.refiner is not None
    plain = with_networks(plan_call("icp", ICPCriteria(), None, **{**ARGUMENTS, "use_mask": False}))
    assert plain.model is None and plain.search_model is None


def test_a_plan_refuses_what_no_stage_could_run():
    with pytest.raises(MaskNetError, match="mask network"):
        plan_call("icp", ICPCriteria(), "modelnet40", **ARGUMENTS)
    with pytest.raises(MaskNetError, match="refines itself"):
        plan_call("robust", RobustOptions(), None, **{**ARGUMENTS, "refine_iterations": 5})

"""masknet.registration.plan: what a call resolves before it touches the clouds, and the
default networks it loads once."""

from __future__ import annotations

import pytest

from masknet import MaskNetError, register
from masknet.models import CrossMaskNet, MaskNet
from masknet.models.two_sided import TwoSidedMaskNet
from masknet.registration.plan import (
    FAST_PATH_WEIGHTS,
    MASK_X_METHODS,
    default_fast_model,
    default_mask_x_model,
    default_model,
    default_two_sided,
    plan_call,
    with_networks,
)
from masknet.registration.terms.methods import METHOD_TABLE
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
    assert one_round.model is default_mask_x_model() and one_round.refiner is None
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


def test_every_mask_x_masks_with_the_shipped_crossmasknet():
    assert set(MASK_X_METHODS) == {"icp", "pointnetlk", "dcp", "prnet", "pcrnet", "rpmnet"}
    model = default_mask_x_model()
    assert isinstance(model, CrossMaskNet) and model.config.get("descriptors") == "fpfh"
    for method in MASK_X_METHODS:
        options = METHOD_TABLE[method].options()
        assert with_networks(plan_call(method, options, None, **ARGUMENTS)).model is model
    # Open3D's ICP keeps the paper's network, and so does "auto" (its small one).
    open3d_icp = plan_call("open3d-icp", METHOD_TABLE["open3d-icp"].options(), None, **ARGUMENTS)
    assert with_networks(open3d_icp).model is default_model()
    auto = with_networks(plan_call("auto", RobustOptions(), None, **ARGUMENTS))
    assert auto.model is default_fast_model()


def test_the_paper_masknet_is_one_argument_away():
    paper = MaskNet.pretrained()
    options = METHOD_TABLE["pointnetlk"].options()
    given = with_networks(plan_call("pointnetlk", options, paper, **ARGUMENTS))
    assert given.model is paper and type(given.model) is MaskNet


def test_mask_x_registers_a_batch_with_crossmasknet():
    from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs

    points = load_modelnet40(bundled_sample_path(), "test").points
    pairs = make_test_pairs(points, 2, PairConfig(), seed=3)
    template, source = pairs.template.numpy(), pairs.source.numpy()
    result = register(template, source, method="pcrnet")
    assert result.transform.shape == (2, 4, 4) and result.mask.shape == (2, 1024)
    # The batch's masks are CrossMaskNet's, pair by pair, and mostly the true ones.
    alone = default_mask_x_model().predict_mask(template[1], source[1], precision="fp32")
    assert (result.mask[1] == alone).mean() > 0.99
    truth = pairs.mask.numpy().astype(bool)
    assert ((result.mask & truth).sum(1) / source.shape[1]).min() > 0.9


def test_without_open3d_mask_x_still_masks_with_crossmasknet(monkeypatch):
    """Without Open3D, CrossMaskNet's FPFH inputs come from numpy: the same mask."""
    from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
    from masknet.models import descriptors

    points = load_modelnet40(bundled_sample_path(), "test").points
    pair = make_test_pairs(points, 1, PairConfig(), seed=5)
    template, source = pair.template[0].numpy(), pair.source[0].numpy()
    model = default_mask_x_model()
    assert isinstance(model, CrossMaskNet)
    with_open3d = model.predict_mask(template, source, precision="fp32")

    def missing(feature: str):
        raise MaskNetError(f"{feature} needs Open3D")

    monkeypatch.setattr(descriptors, "require_open3d", missing)
    without = model.predict_mask(template, source, precision="fp32")
    assert (without == with_open3d).mean() > 0.99

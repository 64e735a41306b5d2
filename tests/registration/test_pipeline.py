"""The stages of a register() call, one at a time."""

import numpy as np
import pytest

from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.errors import MaskNetError
from masknet.registration.pipeline import (
    check_clouds,
    enter_frame,
    leave_frame,
    measure_fit,
    refine_plain,
)
from masknet.registration.plan import CallPlan, plan_call
from masknet.registration.terms.methods import method_options
from masknet.registration.terms.result import Solution

ARGUMENTS = dict(
    use_mask=False,
    iterations=1,
    refine_iterations=0,
    k=None,
    threshold=None,
    precision="fp32",
    init="centroid",
    max_points=1024,
    scene=False,
    refine_masks=None,
    drop_nonfinite=False,
)


def plan_for(method: str = "icp", options: dict | None = None, **changes) -> CallPlan:
    """A checked plan of ``method`` with its ``options`` given inline, as register makes it."""
    typed = method_options(method, None, options or {})
    return plan_call(method, typed, None, **(ARGUMENTS | changes))


@pytest.fixture(scope="module")
def clouds():
    pairs = make_test_pairs(load_modelnet40(bundled_sample_path()).points, 1, PairConfig(), seed=0)
    return pairs.template[0].double().numpy(), pairs.source[0].double().numpy()


def test_plan_refuses_what_no_stage_runs():
    with pytest.raises(MaskNetError, match="refine_iterations is for the rounds"):
        plan_for("auto", refine_iterations=3)
    options = method_options("icp", None, {})
    with pytest.raises(MaskNetError, match="model must be a mask network"):
        plan_call("icp", options, "weights.safetensors", **ARGUMENTS)


def test_check_clouds_refuses_bad_clouds_and_drops_nonfinite_rows(clouds):
    template, source = clouds
    with pytest.raises(MaskNetError, match="NaN"):
        check_clouds(np.full((10, 3), np.nan), source, plan_for())
    template = template.copy()
    template[4] = np.nan
    checked = check_clouds(template, source, plan_for(drop_nonfinite=True))
    assert checked.template.shape == (1, len(template) - 1, 3)
    assert checked.single and not checked.template_rows[4] and checked.template_rows.sum() == 1023


def test_the_frame_is_unit_free_and_converts_distances(clouds):
    template, source = clouds
    times = {}
    plan = plan_for(options={"max_correspondence_distance": 0.1})
    pair_m, plan_m = enter_frame(check_clouds(template, source, plan), plan, times)
    plan_mm = plan_for(options={"max_correspondence_distance": 100.0})
    pair_mm, plan_mm = enter_frame(
        check_clouds(template * 1000, source * 1000, plan_mm), plan_mm, times
    )
    np.testing.assert_array_equal(
        pair_m.template, pair_mm.template
    )  # the same numbers in the frame
    assert plan_m.options.max_correspondence_distance == pytest.approx(
        plan_mm.options.max_correspondence_distance
    )
    assert plan_m.options.max_correspondence_distance == pytest.approx(0.1 / pair_m.frame.scale)
    assert "sample" not in times  # the networks' clouds are sampled on first use
    assert pair_m.sampled_template.shape == pair_m.template.shape  # 1,024 points: kept whole
    assert "sample" in times


def test_large_clouds_are_sampled_for_the_networks(clouds):
    template, source = clouds
    plan = plan_for(max_points=256)
    times = {}
    pair, _ = enter_frame(check_clouds(template, source, plan), plan, times)
    assert pair.nets.sizes() == (1024, len(source))  # nothing sampled yet
    assert pair.sampled_template.shape == (1, 256, 3)
    assert times["sample"] > 0 and pair.nets.sizes()[0] == 256
    assert pair.template.shape == (1, 1024, 3)  # the full clouds stay beside them
    assert pair.template_index.shape == (256,)


def test_leave_frame_maps_the_transform_out_and_spreads_masks(clouds):
    template, source = clouds
    plan = plan_for(max_points=256)
    pair, plan = enter_frame(check_clouds(template * 50 + 3, source * 50 + 3, plan), plan, {})
    sampled_mask = np.zeros((1, 256), bool)
    sampled_mask[0, :100] = True
    found = Solution(
        np.eye(4)[None], sampled_mask, None, {"inlier_rmse": np.array([0.01])}, [np.eye(4)]
    )
    result = leave_frame(pair, found, plan, {})
    np.testing.assert_allclose(result.transform, np.eye(4), atol=1e-12)  # identity in any frame
    assert result.mask.shape == (1024,)  # spread to every template point
    assert result.mask[pair.template_index[:100]].all()
    assert result.info["inlier_rmse"] == pytest.approx(0.01 * pair.frame.scale)


def test_measure_fit_measures_once_and_leaves_a_one_round_pipeline(clouds):
    template, source = clouds
    plan = plan_for()
    pair, plan = enter_frame(check_clouds(template, template, plan), plan, {})
    found = Solution(np.eye(4)[None], info={"fitness": np.array([0.25])}, rounds=[])
    measured = measure_fit(pair, found, plan)
    assert measured.info["fitness"][0] == 1.0  # the source is the template: every point fits
    auto = plan_for("auto")
    pair, auto = enter_frame(check_clouds(template, template, auto), auto, {})
    assert measure_fit(pair, found, auto).info["fitness"][0] == 0.25  # the pipeline's own


def test_refine_plain_runs_only_when_asked(clouds):
    template, source = clouds
    plan = plan_for()
    pair, plan = enter_frame(check_clouds(template, template, plan), plan, {})
    start = np.eye(4)[None].copy()
    start[0, :3, 3] = 0.02
    found = Solution(start, info={}, rounds=[])
    assert refine_plain(pair, found, plan, {}) is found
    refined = refine_plain(pair, found, plan_for(refine_iterations=20), {"refine": 0.0})
    assert np.abs(refined.transform[0, :3, 3]).max() < 1e-3  # back on the template

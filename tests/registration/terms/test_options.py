"""masknet.registration.terms.options: one typed options object per method, checked when made,
and the same thing as its fields spelled as keywords."""

from __future__ import annotations

import numpy as np
import pytest

from masknet import MaskNetError, register
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.registration import (
    FGROptions,
    ICPCriteria,
    NetworkOptions,
    Open3DICPOptions,
    PointNetLKOptions,
    RANSACOptions,
    RobustOptions,
)
from masknet.registration.terms.methods import METHOD_TABLE


@pytest.fixture(scope="module")
def pair():
    shapes = load_modelnet40(bundled_sample_path(), "test").points
    pairs = make_test_pairs(shapes, 1, PairConfig(), seed=2)
    return pairs.template[0].numpy(), pairs.source[0].numpy()


def test_an_options_object_equals_its_keywords(pair, small_masknet):
    template, source = pair
    typed = register(template, source, model=small_masknet, options=ICPCriteria(max_iterations=25))
    keywords = register(template, source, method="icp", model=small_masknet, max_iterations=25)
    assert typed.method == keywords.method == "icp"  # the options' class names the method
    np.testing.assert_array_equal(typed.transform, keywords.transform)
    # ... and the budget is used: 25 iterations end elsewhere than 1
    one = register(template, source, method="icp", model=small_masknet, max_iterations=1)
    assert not np.allclose(one.transform, typed.transform)


def test_robust_options_object(pair):
    template, source = pair
    typed = RobustOptions(hypotheses=4, candidates=2)
    a = register(template, source, method="robust", options=typed)
    b = register(template, source, method="robust", hypotheses=4, candidates=2)
    np.testing.assert_array_equal(a.transform, b.transform)
    assert register(template, source, options=typed).method == "auto"


def test_an_object_and_its_keywords_cannot_both_be_given(pair):
    template, source = pair
    with pytest.raises(MaskNetError, match=r"give options=ICPCriteria\(...\) or its fields"):
        register(template, source, options=ICPCriteria(), max_iterations=3)
    with pytest.raises(MaskNetError, match="method 'icp' takes options=ICPCriteria"):
        register(template, source, method="icp", options=RobustOptions())
    with pytest.raises(MaskNetError, match="NetworkOptions serves dcp, prnet, pcrnet, rpmnet"):
        register(template, source, options=NetworkOptions())
    with pytest.raises(MaskNetError, match="unknown option.*'icp': tolerance"):
        register(template, source, method="icp", tolerance=1e-6)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: ICPCriteria(max_iterations=-1), "max_iterations must be an integer >= 0"),
        (lambda: ICPCriteria(max_correspondence_distance=0), "max_correspondence_distance"),
        (lambda: ICPCriteria(relative_rmse=-1), "relative_rmse must be a number >= 0"),
        (lambda: Open3DICPOptions(max_iterations=2.5), "max_iterations must be an integer"),
        (lambda: NetworkOptions(max_iterations=0), "max_iterations must be an integer >= 1"),
        (lambda: PointNetLKOptions(tolerance=-1), "tolerance must be a number >= 0"),
        (lambda: RANSACOptions(confidence=2), r"confidence must be in \(0, 1\]"),
        (lambda: FGROptions(voxel_size=0), "voxel_size must be a positive number"),
        (lambda: RobustOptions(hypotheses=30), r"hypotheses must be in \[0, 24\]"),
        (lambda: RobustOptions(max_correspondence_distance=-1), "max_correspondence_distance"),
        (lambda: RobustOptions(search_first_turn_deg=120), r"search_first_turn_deg in \(0, 90\]"),
        (lambda: RobustOptions(search_first_turn_deg="50"), "search_first_turn_deg"),
        (lambda: RobustOptions(object_accept_fitness=1.5), "object_accept_fitness"),
        (lambda: RobustOptions(object_accept_fitness="0.9"), "object_accept_fitness"),
    ],
)
def test_options_are_checked_when_made(make, message):
    with pytest.raises(MaskNetError, match=message):
        make()


def test_every_method_has_an_options_class_that_builds_with_defaults():
    for name, entry in METHOD_TABLE.items():
        options = entry.options()
        assert type(options).__name__.endswith(("Options", "Criteria")), name
        if entry.default_iterations is not None:
            assert "max_iterations" in {f for f in options.__dataclass_fields__}, name


def test_each_method_takes_its_own_options_class_and_numpy_scalars(pair):
    from masknet.registration import PointNetLKOptions

    template, source = pair
    with pytest.raises(MaskNetError, match="method 'dcp' takes options=NetworkOptions"):
        register(template, source, method="dcp", options=PointNetLKOptions(tolerance=0.5))
    assert ICPCriteria(max_iterations=np.int64(5), max_correspondence_distance=np.float32(0.05))
    with pytest.raises(MaskNetError, match="ransac_trials must be an integer"):
        RobustOptions(ransac_trials=2.5)


def test_pipelines_refuse_refine_iterations(pair):
    template, source = pair
    with pytest.raises(MaskNetError, match="refine_iterations is for the rounds' methods"):
        register(template, source, method="robust", refine_iterations=10)


def test_the_hypotheses_short_icp_takes_a_share_of_large_sources():
    from masknet.registration.terms.options import RobustOptions

    options = RobustOptions()
    assert options.hypothesis_size(512) == options.hypothesis_size(2048) == 128
    assert options.hypothesis_size(4096) == 256
    assert RobustOptions(hypothesis_points=300).hypothesis_size(4096) == 300


def test_the_scene_search_options_are_checked_when_made_and_frozen():
    import dataclasses

    from masknet.registration.terms.options import SceneSearch

    for bad, field in (
        ({"trim": 0}, "trim"),
        ({"voxel": -1.0}, "voxel"),
        ({"candidates": 0}, "candidates"),
    ):
        with pytest.raises(MaskNetError, match=field):
            SceneSearch(**bad)
    with pytest.raises(MaskNetError, match="max_placements"):
        SceneSearch(max_placements=10)  # fewer than one centre's 24 rotations
    with pytest.raises(dataclasses.FrozenInstanceError):
        SceneSearch().voxel = 0.1  # type: ignore[misc]


def test_every_options_class_is_exported_at_the_top_level():
    import masknet
    from masknet.registration.terms import options

    classes = [n for n in options.__all__ if n[0].isupper() and n != "DEFAULT_SPACINGS"]
    assert "SceneSearch" in classes and "ICPCriteria" in classes
    for name in classes:
        assert getattr(masknet, name) is getattr(options, name)
        assert name in masknet.__all__

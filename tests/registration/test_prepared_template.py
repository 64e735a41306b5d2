"""masknet.prepare_template: a template prepared once gives every call the cold call's
answer (ModelNet40 pairs, the bunny scan, register_many, the tracker), its views kept apart
by key, and a bad template refused in one line."""

from __future__ import annotations

import numpy as np
import pytest

from masknet import MaskNetError, prepare_template, register
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.geometry.prepared_template import PreparedTemplate, template_view, using
from masknet.registration.many import register_many


@pytest.fixture(scope="module")
def one_shape() -> tuple[np.ndarray, list[np.ndarray]]:
    shape = load_modelnet40(bundled_sample_path(), "test").points[:1]
    made = make_test_pairs(np.repeat(shape, 3, 0), 3, PairConfig(max_angle_deg=90), seed=4)
    return made.template[0].double().numpy(), list(made.source.double().numpy())


def _same(cold, warm) -> None:
    np.testing.assert_array_equal(warm.transform, cold.transform)
    np.testing.assert_array_equal(warm.mask, cold.mask)
    assert warm.info["path"] == cold.info["path"]
    assert warm.info["fitness"] == cold.info["fitness"]


def test_prepared_calls_equal_cold_calls(one_shape):
    template, sources = one_shape
    prepared = prepare_template(template)
    for source in sources:
        _same(register(template, source), register(prepared, source))
    assert prepared.views >= 2 and prepared.hits >= 2  # built once, then served


def test_a_scan_sized_template_too(scans_dir):
    from masknet.io import read_points

    bunny = read_points(scans_dir / "bun_zipper_res3.ply")
    prepared = prepare_template(bunny)
    for keep, turn in ((0.7, 0.2), (0.6, -0.3)):
        part = bunny[bunny[:, 0] < np.quantile(bunny[:, 0], keep)]
        c, s = np.cos(turn), np.sin(turn)
        source = part @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T + 0.01
        _same(register(bunny, source), register(prepared, source))
    # The networks' sample of the 1,889-point bunny is one of the views kept.
    assert prepared.views >= 4


def test_units_and_methods_keep_their_own_views(one_shape):
    template, sources = one_shape
    prepared = prepare_template(template * 1000)
    for source in sources[:2]:  # millimetres: another frame, its own views
        _same(register(template * 1000, source * 1000), register(prepared, source * 1000))
    cold = register(template, sources[0], method="icp", iterations=2)
    np.testing.assert_array_equal(
        register(prepare_template(template), sources[0], method="icp", iterations=2).transform,
        cold.transform,
    )


def test_views_are_kept_apart_by_key_and_array():
    points = np.random.default_rng(0).normal(size=(50, 3))
    prepared = PreparedTemplate(points)
    other = points.copy()  # the same values, not an array the template handed out
    with using(prepared):
        assert template_view(prepared.points, ("a", 1), lambda: "built a1") == "built a1"
        assert template_view(prepared.points, ("a", 1), lambda: "again") == "built a1"
        assert template_view(prepared.points, ("a", 2), lambda: "built a2") == "built a2"
        assert template_view(other, ("a", 1), lambda: "cold") == "cold"
    assert template_view(prepared.points, ("a", 1), lambda: "inactive") == "inactive"
    assert prepared.views == 2 and prepared.hits == 1
    with pytest.raises(ValueError):  # a view is read-only: no stage can change it
        prepared.points[0, 0] = 1.0


def test_a_full_cache_builds_new_views_cold(one_shape, monkeypatch):
    from masknet.geometry import prepared_template

    template, sources = one_shape
    monkeypatch.setattr(prepared_template, "MAX_VIEWS", 2)
    prepared = prepare_template(template)
    for source in sources:
        _same(register(template, source), register(prepared, source))
    assert prepared.views == 2  # the frame and one more; the rest built as cold calls do


@pytest.mark.parametrize(
    "bad, words",
    [
        (np.zeros((10, 3)), "identical"),
        (np.full((10, 3), np.nan), "NaN"),
        (np.zeros((2, 10, 3)), "one template"),
    ],
)
def test_a_bad_template_is_refused_in_one_line(bad, words):
    with pytest.raises(MaskNetError) as caught:
        prepare_template(bad)
    assert words in str(caught.value) and "\n" not in str(caught.value)


def test_register_many_with_one_prepared_template(one_shape, one_thread):
    template, sources = one_shape
    prepared = prepare_template(template)
    pooled = register_many([(prepared, s) for s in sources], workers=2)
    here = register_many([(prepared, s) for s in sources], workers=0)
    for source, a, b in zip(sources, pooled, here, strict=True):
        cold = register(template, source)
        np.testing.assert_array_equal(a.transform, cold.transform)
        np.testing.assert_array_equal(b.transform, cold.transform)


def test_a_template_shared_with_workers_is_the_one_they_restore(one_shape):
    import pickle

    from masknet.geometry.prepared_template import share_with_workers

    template, sources = one_shape
    prepared = share_with_workers(prepare_template(template))
    register(prepared, sources[0])
    views = prepared.views
    # What a forked worker does with a job's pickle: it finds the parent's, views and all.
    assert pickle.loads(pickle.dumps(prepared)) is prepared
    assert prepared.views == views > 0
    other = pickle.loads(pickle.dumps(prepare_template(template)))
    assert other is not prepared and other.views == 0

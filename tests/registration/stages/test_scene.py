"""masknet.registration.stages.scene: finding a small object in a large scene, alone and in register."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from masknet import MaskNetError, register
from masknet.data import bundled_sample_path, load_modelnet40
from masknet.evaluation.registration import pose_errors
from masknet.geometry.clouds import unit_radius
from masknet.registration.stages.scene import SceneSearch, is_scene, locate, polish

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def scene_pair():
    """A sample shape (the object), and a scene of seven other shapes on a 3 x 3 grid (three
    radii apart) with the object, turned by 120 degrees, in one of its cells, plus a floor.
    Returns (object, scene, truth (4, 4) scene -> object, (P,) bool scene points on it)."""
    shapes = load_modelnet40(bundled_sample_path(), "test").points.astype(np.float64)
    obj = shapes[0]
    rot = Rotation.from_rotvec(np.radians(120) * np.array([0.0, 0.6, 0.8])).as_matrix()
    rng = np.random.default_rng(0)
    parts, on_object = [], []
    for i, (x, y) in enumerate((x, y) for x in range(3) for y in range(3)):
        if i == 8:
            continue
        shift = np.array([3.0 * x, 3.0 * y, 0.0])
        if i == 4:  # the object in the middle cell: 700 of its points, with noise
            points = obj[rng.choice(len(obj), 700, replace=False)] @ rot.T + shift
            points = points + rng.normal(0, 0.005, points.shape)
            object_shift = shift
        else:
            points = shapes[i + 1] + shift
        parts.append(points)
        on_object.append(np.full(len(points), i == 4))
    floor = np.c_[rng.uniform(-1.5, 7.5, (3000, 2)), np.full(3000, -1.2)]
    parts.append(floor)
    on_object.append(np.zeros(len(floor), bool))
    scene = np.concatenate(parts)
    truth = np.eye(4)  # scene -> object frame
    truth[:3, :3], truth[:3, 3] = rot.T, -rot.T @ object_shift
    return obj, scene, truth, np.concatenate(on_object)


def test_locate_finds_the_object_and_its_points(scene_pair):
    obj, scene, truth, on_object = scene_pair
    found = locate(obj, scene)
    rot, trans = pose_errors(found.transform[None], truth[None])
    assert rot[0] < 1.0 and trans[0] < 0.02
    assert found.coverage > 0.6  # a new sampling of 700 points against 1,024
    kept = found.source_mask
    assert kept.shape == (len(scene),)
    assert (kept & on_object).sum() > 0.95 * on_object.sum()  # the object's points...
    assert (kept & ~on_object).sum() < 0.05 * kept.sum()  # ...and little else
    assert found.regions > 10 and found.hypotheses == 24 * found.regions


def test_locate_does_not_depend_on_the_unit(scene_pair):
    obj, scene, _, _ = scene_pair
    metres = locate(obj, scene)
    millimetres = locate(1000 * obj, 1000 * scene)
    np.testing.assert_allclose(millimetres.transform[:3, :3], metres.transform[:3, :3], atol=1e-6)
    np.testing.assert_allclose(
        millimetres.transform[:3, 3], 1000 * metres.transform[:3, 3], atol=1e-3
    )
    np.testing.assert_array_equal(millimetres.source_mask, metres.source_mask)


def test_register_searches_a_scene_by_default_and_not_a_view(scene_pair):
    obj, scene, truth, on_object = scene_pair
    assert is_scene(obj, scene) and not is_scene(obj, obj[:500])
    result = register(obj, scene)  # Mask-ICP after the search
    rot, trans = pose_errors(result.transform[None], truth[None])
    assert rot[0] < 1.0 and trans[0] < 0.02
    assert result.source_mask.shape == (len(scene),)
    assert (result.source_mask & on_object).sum() > 0.9 * on_object.sum()
    assert result.scene.coverage > 0.6 and result.times["search"] > 0
    view = register(obj, obj[:500] + 0.05)
    assert view.scene is None and "search" not in view.times


def test_a_large_scene_gets_a_coarser_grid_within_the_budget(scene_pair):
    obj, scene, truth, _ = scene_pair
    found = locate(obj, scene, SceneSearch(max_placements=24 * 60))
    assert found.hypotheses <= 24 * 60 and found.spacing > 0.5
    assert locate(obj, scene).spacing == 0.5
    with pytest.raises(MaskNetError, match="max_placements"):
        SceneSearch(max_placements=10).check()


def test_scene_search_off_and_bad_uses(scene_pair):
    obj, scene, truth, _ = scene_pair
    plain = register(obj, scene, scene=False)
    assert plain.scene is None
    assert pose_errors(plain.transform[None], truth[None])[0][0] > 10  # ICP alone is lost
    with pytest.raises(MaskNetError, match="one pair"):
        register(np.stack([obj, obj]), np.stack([obj, obj]), scene=True)
    with pytest.raises(MaskNetError, match="trim"):
        locate(obj, scene, SceneSearch(trim=0))
    with pytest.raises(MaskNetError, match="no region"):
        locate(obj, scene[:10], SceneSearch(min_region_points=50))


def test_polish_keeps_an_exact_pose_and_picks_the_better_start(scene_pair):
    obj, scene, truth, on_object = scene_pair
    points = scene[on_object]
    off = truth.copy()
    off[:3, 3] += [0.5, 0.0, 0.0]  # half a radius away: ICP with a tight cut cannot recover
    best = polish(obj, points, [off, truth])
    rot, trans = pose_errors(best[None], truth[None])
    assert rot[0] < 1.0 and trans[0] < 0.02
    assert pose_errors(polish(obj, points, [off])[None], truth[None])[1][0] > 0.1


def test_auto_search_falls_back_where_it_finds_nothing():
    shapes = load_modelnet40(bundled_sample_path(), "test").points.astype(np.float64)
    sparse = np.random.default_rng(0).uniform(-10, 10, (500, 3))  # nothing dense enough
    assert is_scene(shapes[0], sparse)
    result = register(shapes[0], sparse)  # registered as it is, no error
    assert result.scene is None
    with pytest.raises(MaskNetError, match="no region"):
        register(shapes[0], sparse, scene=True)
    assert not is_scene(np.zeros((10, 3)), sparse)  # a template with no spread: never


def test_a_viewpoint_scores_the_side_facing_the_sensor(scene_pair):
    from masknet.registration.stages.scene import _facing, _outward_normals

    rng = np.random.default_rng(1)
    sphere = rng.normal(size=(400, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    normals = _outward_normals(sphere)
    assert (np.einsum("ij,ij->i", normals, sphere) > 0.9).mean() > 0.95  # outward
    facing = _facing(np.eye(4)[None], sphere[None], normals, np.array([0.0, 0.0, 10.0]))[0]
    assert (facing == (sphere[:, 2] > 0.1)).mean() > 0.97  # the cap z > 0.1 faces the sensor
    obj, scene, truth, on_object = scene_pair
    found = locate(obj, scene, SceneSearch(viewpoint=(3.0, 3.0, 10.0)))
    rot, trans = pose_errors(found.transform[None], truth[None])
    assert rot[0] < 1.0 and trans[0] < 0.02
    # The object here is sampled all round: the side facing the sensor is about half of it.
    kept = found.source_mask
    assert (kept & on_object).sum() > 0.4 * on_object.sum() and (kept & ~on_object).sum() < 20
    with pytest.raises(MaskNetError, match="viewpoint"):
        SceneSearch(viewpoint=(0.0, np.nan, 1.0)).check()


def test_placements_are_dropped_early_and_their_points_grow():
    """Drops after 2, 5 and 10 iterations and every 5 after; the points grow from an eighth
    (at least 16) at each of the first three drops."""
    from masknet.registration.stages import scene

    assert [i for i in range(31) if scene._drops(i)] == [2, 5, 10, 15, 20, 25, 30]
    assert [scene._points_at(i, 256) for i in (0, 1, 2, 5, 10, 14)] == [32, 32, 64, 128, 256, 256]
    assert [scene._points_at(i, 64) for i in (0, 2, 5, 10)] == [16, 16, 32, 64]


@pytest.mark.parametrize("points", [40, 64, 500, 1024, 3000])
def test_the_placements_take_farthest_points_and_the_refinement_an_even_grid(points):
    """The placements' few points are the farthest-point sample of their size; the
    refinement's many an even grid subset of the template (all of a smaller one)."""
    from masknet.geometry.sampling import farthest_point_sample, grid_subset
    from masknet.registration.stages.scene import _Placement

    tpl = np.random.default_rng(1).normal(size=(points, 3))
    opts = SceneSearch()
    placed = _Placement(tpl, None, None, opts)
    hypothesis = farthest_point_sample(tpl, opts.hypothesis_points).indices
    np.testing.assert_array_equal(placed.small, hypothesis)
    np.testing.assert_array_equal(placed.fine, grid_subset(tpl, opts.refine_points))
    assert len(placed.fine) <= opts.refine_points
    if points <= opts.refine_points:
        np.testing.assert_array_equal(placed.fine, np.arange(points))


@pytest.mark.parametrize("iterations", [1, 2, 12])
def test_a_short_or_long_search_still_finds_the_object(scene_pair, iterations):
    obj, scene, truth, _ = scene_pair
    found = locate(obj, scene, SceneSearch(max_iterations=iterations))
    assert found.transform.shape == (4, 4) and np.isfinite(found.transform).all()
    if iterations >= 12:
        rot, trans = pose_errors(found.transform[None], truth[None])
        assert rot[0] < 1.0 and trans[0] < 0.02


def test_the_first_steps_look_up_a_field_and_the_refinement_halves(scene_pair, monkeypatch):
    """Before the first drop every placement's matches come from the NearestField (where
    there are FIELD_FROM placements or more); from the drop on, and with a viewpoint
    throughout, from the KD-tree. Every candidate takes the first refinement iterations, a
    quarter the rest. Without the field (fewer placements, or a scene too large for its
    cells) the object is found as well."""
    from masknet.geometry.knn import NearestField
    from masknet.registration.stages import scene

    obj, points, truth, _ = scene_pair
    lookups, refined = [], []
    query, refine = NearestField.query, scene._Placement._refined

    def counted_query(self, *args, **kwargs):
        lookups.append(1)
        return query(self, *args, **kwargs)

    def counted_refine(self, *args):
        refined.append(args[-1])  # its iterations
        return refine(self, *args)

    monkeypatch.setattr(NearestField, "query", counted_query)
    monkeypatch.setattr(scene._Placement, "_refined", counted_refine)
    few = locate(obj, points)
    assert not lookups and few.hypotheses < scene.FIELD_FROM  # too few placements for it
    monkeypatch.setattr(scene, "FIELD_FROM", 0)
    refined.clear()
    found = locate(obj, points)
    opts = SceneSearch()
    assert len(lookups) == scene.FIELD_UNTIL + 1
    total, first, kept = 2 * opts.max_iterations, scene.REFINE_FIRST, opts.candidates // 4
    assert refined == [first] * opts.candidates + [total - first] * kept
    rot, trans = pose_errors(found.transform[None], truth[None])
    assert rot[0] < 1.0 and trans[0] < 0.02
    lookups.clear()
    locate(obj, points, SceneSearch(viewpoint=(3.0, 3.0, 8.0), max_iterations=3))
    assert not lookups  # with a viewpoint the tree serves throughout
    monkeypatch.setattr(scene, "FIELD_MAX_CELLS", 10)
    assert scene._coarse_field(points) is None
    lookups.clear()
    without = locate(obj, points)
    assert not lookups
    rot, trans = pose_errors(without.transform[None], truth[None])
    assert rot[0] < 1.0 and trans[0] < 0.02


def test_the_fit_and_mask_near_the_object_are_the_whole_scenes(scene_pair):
    """locate measures its coverage and source mask on the scene points within the
    template's reach of the pose: the same as on the whole scene."""
    from masknet.geometry.knn import cloud_tree
    from masknet.geometry.se3 import transform_points
    from masknet.registration.stages.scene import _inlier_distance

    obj, points, _, _ = scene_pair
    found = locate(obj, points)
    radius = float(unit_radius(obj))
    tolerance = radius * _inlier_distance((obj - obj.mean(0)) / radius, SceneSearch())
    moved = transform_points(np.linalg.inv(found.transform), obj)  # template in the scene
    dist, _ = cloud_tree(points).query(moved, k=1)
    assert found.coverage == pytest.approx(float((dist <= tolerance).mean()), abs=1e-9)
    near = cloud_tree(moved).query(points, k=1, distance_upper_bound=tolerance)[0]
    np.testing.assert_array_equal(found.source_mask, np.isfinite(near))


def test_after_a_scene_search_the_default_masks_with_the_papers_network(scene_pair, monkeypatch):
    """The fast path's small network is not the one of the Mask-ICP after a scene search."""
    from masknet.registration import plan

    obj, points, truth, _ = scene_pair

    def refused():
        raise AssertionError("the small network ran after a scene search")

    monkeypatch.setattr(plan, "default_fast_model", refused)
    result = register(obj, points)
    assert result.info["path"] == "scene search" and type(result.info["path"]) is str
    rot, trans = pose_errors(result.transform[None], truth[None])
    assert rot[0] < 1.0 and trans[0] < 0.02

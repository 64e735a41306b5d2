"""masknet.registration.stages.scene_centres: the candidate centres of the scene search, and the
share of them whose surroundings look like the template."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from masknet import MaskNetError
from masknet.data import bundled_sample_path, load_modelnet40
from masknet.geometry.clouds import unit_radius
from masknet.geometry.knn import cloud_tree
from masknet.registration.stages import scene_centres
from masknet.registration.stages.scene_centres import (
    MIN_CENTRES,
    candidate_centres,
    centre_scores,
    likely_centres,
    voxel_thin,
)
from masknet.registration.terms.options import SceneSearch

pytest.importorskip("open3d")


@pytest.fixture(scope="module")
def shelf():
    """A sample shape and a scene: the shape, turned, among 15 other shapes on a 4 x 4 grid
    four radii apart, over a floor; all in the search's frame (the shape's centroid, unit
    radius). Returns (template (N, 3), thinned scene (T, 3), its centres (C, 3), the shape's
    centre in the scene (3,))."""
    shapes = load_modelnet40(bundled_sample_path(), "test").points.astype(np.float64)
    obj = shapes[0]
    centre, radius = obj.mean(0), float(unit_radius(obj))
    rot = Rotation.from_rotvec(np.radians(100) * np.array([0.6, 0.0, 0.8])).as_matrix()
    rng = np.random.default_rng(0)
    parts, where = [], None
    for i in range(16):
        shift = np.array([4.0 * (i // 4), 4.0 * (i % 4), 0.0])
        if i == 9:
            points = obj[rng.choice(len(obj), 700, replace=False)] @ rot.T + shift
            where = centre @ rot.T + shift
        else:
            points = shapes[1 + i % (len(shapes) - 1)] + shift
        parts.append(points)
    parts.append(np.c_[rng.uniform(-1.5, 13.5, (6000, 2)), np.full(6000, -1.2)])
    scene = (np.concatenate(parts) - centre) / radius
    tpl = (obj - centre) / radius
    thin = voxel_thin(scene, SceneSearch().voxel)
    centres, _ = candidate_centres(thin, cloud_tree(thin, np.float32), SceneSearch())
    return tpl, thin, centres, (where - centre) / radius


def test_the_centres_kept_are_the_share_that_looks_most_like_the_template(shelf):
    tpl, thin, centres, truth = shelf
    assert len(centres) > 2 * MIN_CENTRES  # a scene large enough to be cut
    opts = SceneSearch()
    kept = likely_centres(tpl, thin, centres, opts)
    assert len(kept) == max(math.ceil(opts.centre_share * len(centres)), MIN_CENTRES)
    assert len(kept) < len(centres)
    # The centre nearest the object's own is among those searched.
    nearest = centres[np.argmin(np.linalg.norm(centres - truth, axis=1))]
    assert (np.linalg.norm(kept - nearest, axis=1) < 1e-12).any()
    # It scores in the best tenth of all centres.
    scores = centre_scores(tpl, thin, centres, opts.feature_voxel)
    assert scores.shape == (len(centres),) and ((scores >= 0) & (scores <= 1)).all()
    rank = int((scores > scores[np.argmin(np.linalg.norm(centres - truth, axis=1))]).sum())
    assert rank < 0.1 * len(centres)


def test_every_centre_is_kept_where_the_share_is_one_or_there_are_no_features(shelf, monkeypatch):
    tpl, thin, centres, _ = shelf
    every = likely_centres(tpl, thin, centres, SceneSearch(centre_share=1.0))
    np.testing.assert_array_equal(every, centres)
    few = centres[: MIN_CENTRES - 1]
    np.testing.assert_array_equal(likely_centres(tpl, thin, few, SceneSearch()), few)
    monkeypatch.setattr(scene_centres, "has_open3d", lambda: False)
    np.testing.assert_array_equal(likely_centres(tpl, thin, centres, SceneSearch()), centres)


@pytest.mark.parametrize("share", [0.0, -0.5, 1.5, float("nan")])
def test_a_bad_share_or_feature_grid_is_one_clear_error(share):
    with pytest.raises(MaskNetError, match="centre_share"):
        SceneSearch(centre_share=share)
    with pytest.raises(MaskNetError, match="feature_voxel"):
        SceneSearch(feature_voxel=0.0)


def test_no_region_large_enough_is_one_clear_error():
    sparse = np.random.default_rng(0).uniform(-20, 20, (40, 3))
    with pytest.raises(MaskNetError, match="no region of the scene holds"):
        candidate_centres(sparse, cloud_tree(sparse, np.float32), SceneSearch())

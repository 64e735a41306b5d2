"""masknet.registration.solvers.correspondences and the batched solvers it uses."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.evaluation.registration import pose_errors
from masknet.registration.solvers.correspondences import (
    compatible_poses,
    feature_cloud,
    fpfh_features,
    mutual_matches,
    ransac_poses,
    voxel_for,
)


def _pose(degrees: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(np.radians(degrees) * rng.normal(size=3) / 1.7).as_matrix()
    out[:3, 3] = rng.normal(size=3)
    return out


def test_ransac_finds_the_pose_among_60_percent_wrong_matches():
    rng = np.random.default_rng(0)
    truth = _pose(120, 1)
    source = rng.uniform(-1, 1, (200, 3))
    template = source @ truth[:3, :3].T + truth[:3, 3]
    wrong = rng.random(200) < 0.6
    template[wrong] = rng.uniform(-2, 2, (int(wrong.sum()), 3))  # matches to nowhere
    found = ransac_poses(source, template, threshold=0.01, trials=2000, keep=3)
    rot, trans = pose_errors(found.transform[:1], truth[None])
    assert rot[0] < 1e-6 and trans[0] < 1e-6
    assert found.inliers[0] == int((~wrong).sum())  # exactly the right matches explain it
    assert (np.diff(found.inliers) <= 0).all()


def test_compatible_groups_find_the_pose_where_ransac_draws_no_right_sample():
    # 20 right matches among 600: a draw of three is all right once in 27,000.
    rng = np.random.default_rng(0)
    truth = _pose(150, 2)
    source = rng.uniform(-1, 1, (600, 3))
    template = rng.uniform(-2, 2, (600, 3))
    right = rng.choice(600, 20, replace=False)
    template[right] = source[right] @ truth[:3, :3].T + truth[:3, 3]
    starved = ransac_poses(source, template, threshold=0.02, trials=3000, keep=8)
    errors = pose_errors(starved.transform, np.broadcast_to(truth, starved.transform.shape))[0]
    assert not (errors < 1).any()  # RANSAC fails here, so the test can tell
    found = compatible_poses(source, template, threshold=0.02, seeds=10)
    best = found.transform[np.argmax(found.inliers)]
    rot, trans = pose_errors(best[None], truth[None])
    assert rot[0] < 1e-6 and trans[0] < 1e-6
    assert found.inliers.max() == 20


def test_compatible_groups_need_three_matches_and_cap_their_size():
    empty = compatible_poses(np.zeros((2, 3)), np.zeros((2, 3)), 0.1)
    assert empty.transform.shape == (0, 4, 4)
    rng = np.random.default_rng(1)
    source = rng.uniform(-1, 1, (1500, 3))
    truth = _pose(30, 3)
    template = source @ truth[:3, :3].T + truth[:3, 3]
    found = compatible_poses(source, template, threshold=0.01, seeds=2, max_matches=200)
    assert len(found.transform) == 2
    assert (found.inliers == 1500).all()  # refitted on every match, not only the subset


def test_ransac_without_enough_matches_returns_nothing():
    found = ransac_poses(np.zeros((2, 3)), np.zeros((2, 3)), 0.1)
    assert found.transform.shape == (0, 4, 4) and found.inliers.shape == (0,)


def test_mutual_matches_are_each_others_nearest():
    features = np.eye(5)
    shuffled = features[[3, 0, 4, 1, 2]] + 0.01
    pairs = mutual_matches(features, shuffled)
    assert sorted(map(tuple, pairs)) == [(0, 1), (1, 3), (2, 4), (3, 0), (4, 2)]


def test_large_feature_sets_match_through_trees_as_the_matrix_does(o3d, monkeypatch):
    """Above MATRIX_MATCHES pairs the matches come from Open3D's feature KD-trees: the
    same pairs as the distance matrix, and the fallback to every source feature's nearest
    where fewer than 3 are mutual."""
    import masknet.registration.solvers.correspondences as correspondences

    rng = np.random.default_rng(0)
    source = rng.random((400, 33))
    template = np.concatenate([source[rng.permutation(400)] + 1e-3, rng.random((200, 33))])
    by_matrix = mutual_matches(source, template)
    monkeypatch.setattr(correspondences, "MATRIX_MATCHES", 0)
    by_trees = mutual_matches(source, template)
    assert len(by_trees) == 400
    assert sorted(map(tuple, by_trees)) == sorted(map(tuple, by_matrix))
    # Two source features nearest to one template feature: one mutual pair, so all nearest.
    few = mutual_matches(np.array([[0.0, 0], [0.1, 0]]), np.array([[0.05, 0.01], [5.0, 5]]))
    assert sorted(map(tuple, few)) == [(0, 0), (1, 0)]


@pytest.mark.parametrize("scale", [1.0, 1000.0])
def test_voxel_follows_the_cloud_not_its_unit(scale):
    shape = load_modelnet40(bundled_sample_path(), "test").points[0].astype(np.float64)
    voxel = voxel_for(scale * shape, 300, scale * 1.0)
    count = len(feature_cloud(scale * shape, voxel).points)
    assert 200 <= count <= 400  # about the target
    assert voxel == pytest.approx(scale * voxel_for(shape, 300, 1.0), rel=1e-6)


def test_fpfh_of_a_moved_copy_matches_itself():
    shape = load_modelnet40(bundled_sample_path(), "test").points[3].astype(np.float64)
    truth = _pose(90, 2)
    moved = (shape - truth[:3, 3]) @ truth[:3, :3]  # truth maps moved onto shape
    voxel = voxel_for(shape, 1000, 1.0)  # about every point: copies get equal features
    a, b = feature_cloud(moved, voxel), feature_cloud(shape, voxel)
    pairs = mutual_matches(a.features, b.features)
    found = ransac_poses(a.points[pairs[:, 0]], b.points[pairs[:, 1]], 1.5 * voxel, 3000, 1)
    rot, _ = pose_errors(found.transform[:1], truth[None])
    assert rot[0] < 1  # a coarse pose, which ICP then refines


def test_oriented_normals_give_a_turned_cloud_the_same_features():
    """Normals turned towards the centroid make FPFH follow the surface: a cloud turned by
    a large angle keeps most points' features; left as Open3D gives them, the
    signs follow the frame and most points' features change."""
    from masknet.io import require_open3d

    o3d = require_open3d("FPFH features")
    points = load_modelnet40(bundled_sample_path(), "test").points[0].astype(np.float64)
    turned = points @ Rotation.from_euler("xyz", [150, 20, -70], degrees=True).as_matrix().T
    changed = {}
    for orient in (False, True):
        features = []
        for cloud in (points, turned + [3.0, -1.0, 2.0]):
            o3d_cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud))
            features.append(np.asarray(fpfh_features(o3d, o3d_cloud, 0.1, 50, orient).data).T)
        changed[orient] = float((np.abs(features[0] - features[1]).max(1) > 1.0).mean())
    assert changed[True] < 0.15, changed
    assert changed[False] > 0.5, changed

"""masknet.registration: the fit of a pose, and ICP from many starts."""

from __future__ import annotations

import numpy as np
from pykdtree.kdtree import KDTree
from scipy.spatial.transform import Rotation

from masknet.registration.icp import icp, icp_from_starts
from masknet.registration.prepared import pose_fit, pose_fits


def test_fit_counts_points_within_the_distance_and_batched_agrees():
    template = np.c_[np.arange(10.0), np.zeros((10, 2))]
    source = template[:4] + [0, 0.05, 0]
    far = np.eye(4)
    far[:3, 3] = [0, 1.0, 0]
    fit = pose_fit(KDTree(template), source, np.eye(4), 0.1)
    assert fit.fitness == 1.0 and abs(fit.rmse - 0.05) < 1e-12
    fits = pose_fits(KDTree(template), source, np.stack([np.eye(4), far]), 0.1)
    assert fits[0] == fit and fits[1].fitness == 0.0 and fits[1].score < fits[0].score


def test_icp_from_starts_equals_one_icp_per_start():
    rng = np.random.default_rng(1)
    template = rng.normal(size=(300, 3)) * [3, 2, 1]
    rot = Rotation.from_euler("xyz", [10, -20, 15], degrees=True).as_matrix()
    source = (template[:200] - [0.2, 0.1, 0]) @ rot
    starts = np.tile(np.eye(4), (3, 1, 1))
    starts[1, :3, :3] = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    starts[2, :3, :3] = Rotation.from_euler("x", 150, degrees=True).as_matrix()
    batched = icp_from_starts(KDTree(template), template, source, starts, 20)
    for h in range(3):
        one = icp(template, source, starts[h], 20, relative_rmse=0.0).transform[0]
        np.testing.assert_allclose(batched[h], one, atol=1e-8)

"""Tests for masknet.geometry.normals: PCA normals for torch batches and numpy clouds."""

from __future__ import annotations

import numpy as np
import torch

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.geometry.knn import cloud_tree
from masknet.geometry.normals import estimate_normals, normals_at


def test_numpy_normals_equal_the_torch_ones_up_to_sign():
    points = load_modelnet40(bundled_sample_path()).points[0].astype(np.float64)
    ours, idx = estimate_normals(points, k=12)
    theirs = estimate_normals(torch.from_numpy(points)[None], k=12)[0][0].numpy()
    assert ours.shape == points.shape and idx.shape == (len(points), 12)
    np.testing.assert_allclose(np.linalg.norm(ours, axis=1), 1.0, atol=1e-9)
    # ties among equidistant neighbours may differ between the two k-NN searches
    assert np.median(np.abs((ours * theirs).sum(1))) > 1 - 1e-9


def test_numpy_normals_of_a_plane_and_a_given_tree():
    g = np.random.default_rng(0)
    plane = np.concatenate([g.uniform(-1, 1, (500, 2)), np.zeros((500, 1))], 1)
    normals, _ = estimate_normals(plane, tree=cloud_tree(plane))
    np.testing.assert_allclose(np.abs(normals[:, 2]), 1.0, atol=1e-9)


def test_normals_at_a_few_points_are_those_of_the_whole_cloud():
    """normals_at takes a few points' normals as estimate_normals takes every point's."""
    cloud = np.random.default_rng(0).normal(size=(500, 3)) * [1.0, 1.0, 0.2]
    every = estimate_normals(cloud, k=10)[0]
    at = np.array([3, 70, 499])
    few = normals_at(cloud, at, cloud_tree(cloud), k=10)
    np.testing.assert_allclose(np.abs((few * every[at]).sum(1)), 1.0, atol=1e-9)

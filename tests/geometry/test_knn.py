"""Tests for masknet.geometry.knn against a brute-force scipy KD-tree."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from masknet.geometry.knn import KNN, NearestField, cloud_tree, knn_points, nearest_field_cells


def _clouds(b: int, p: int, r: int, dtype=torch.float64, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    query = torch.randn(b, p, 3, generator=g, dtype=dtype)
    reference = torch.randn(b, r, 3, generator=g, dtype=dtype)
    return query, reference


def _expected(query: torch.Tensor, reference: torch.Tensor, k: int):
    dists, idx = [], []
    for q, r in zip(query.double().numpy(), reference.double().numpy(), strict=True):
        d, i = cKDTree(r).query(q, k=k)
        d, i = np.asarray(d).reshape(len(q), k), np.asarray(i).reshape(len(q), k)
        dists.append(d**2)
        idx.append(i)
    return np.stack(dists), np.stack(idx)


@pytest.mark.parametrize("k", [1, 4])
@pytest.mark.parametrize("chunk_size", [4096, 7, 1])
@pytest.mark.parametrize("method", ["tree", "brute"])
def test_knn_matches_kdtree(k, chunk_size, method):
    query, reference = _clouds(2, 37, 50, seed=k)
    result = knn_points(query, reference, k=k, chunk_size=chunk_size, method=method)
    assert isinstance(result, KNN)
    assert result.dists.shape == (2, 37, k) and result.idx.shape == (2, 37, k)
    assert result.idx.dtype == torch.int64
    exp_d, exp_i = _expected(query, reference, k)
    np.testing.assert_array_equal(result.idx.numpy(), exp_i)
    np.testing.assert_allclose(result.dists.numpy(), exp_d, rtol=1e-9, atol=1e-12)


def test_knn_float32_matches_kdtree():
    query, reference = _clouds(3, 64, 40, dtype=torch.float32, seed=5)
    result = knn_points(query, reference, k=3, chunk_size=10, method="brute")
    assert result.dists.dtype == torch.float32
    exp_d, exp_i = _expected(query, reference, 3)
    np.testing.assert_array_equal(result.idx.numpy(), exp_i)
    np.testing.assert_allclose(result.dists.numpy(), exp_d, rtol=1e-4, atol=1e-5)


def test_knn_distances_ascending_and_nonnegative():
    query, reference = _clouds(1, 20, 30, seed=2)
    result = knn_points(query, reference, k=30)
    assert (result.dists >= 0).all()
    assert (result.dists[..., 1:] >= result.dists[..., :-1]).all()
    # k = R returns every reference point once per query.
    assert torch.equal(result.idx.sort(-1).values, torch.arange(30).expand(1, 20, 30))


def test_knn_self_query_finds_itself():
    _, reference = _clouds(2, 1, 25, seed=3)
    result = knn_points(reference, reference, k=1)
    assert torch.equal(result.idx[..., 0], torch.arange(25).expand(2, 25))
    assert result.dists.max() < 1e-10


def test_knn_chunked_equals_unchunked():
    query, reference = _clouds(2, 101, 33, dtype=torch.float32, seed=4)
    a = knn_points(query, reference, k=5)
    b = knn_points(query, reference, k=5, chunk_size=16, method="brute")
    assert torch.equal(a.idx, b.idx)
    torch.testing.assert_close(a.dists, b.dists)


@pytest.mark.parametrize("block_elements", [1, 2 * 33, 10 * 2 * 33 + 5])
def test_knn_block_bound_splits_queries_not_results(block_elements):
    # a bound below one query row per batch still searches one row at a time
    query, reference = _clouds(2, 101, 33, seed=6)
    result = knn_points(query, reference, k=3, block_elements=block_elements, method="brute")
    exp_d, exp_i = _expected(query, reference, 3)
    np.testing.assert_array_equal(result.idx.numpy(), exp_i)
    np.testing.assert_allclose(result.dists.numpy(), exp_d, rtol=1e-9, atol=1e-12)


def test_knn_k_larger_than_reference_raises():
    query, reference = _clouds(1, 5, 4)
    with pytest.raises(ValueError, match="k=5"):
        knn_points(query, reference, k=5)


def test_knn_bad_shapes_raise():
    query, reference = _clouds(2, 5, 6)
    with pytest.raises(ValueError):
        knn_points(query[0], reference[0])
    with pytest.raises(ValueError):
        knn_points(query, reference[:1])


def test_knn_reference_valid_matches_kdtree_on_valid_subset():
    query, reference = _clouds(2, 31, 40, seed=6)
    g = torch.Generator().manual_seed(6)
    valid = torch.rand(2, 40, generator=g) < 0.5
    result = knn_points(query, reference, k=3, chunk_size=8, reference_valid=valid, method="brute")
    for b in range(2):
        kept = torch.nonzero(valid[b])[:, 0]
        exp_d, exp_i = _expected(query[b : b + 1], reference[b : b + 1, kept], 3)
        np.testing.assert_array_equal(result.idx[b].numpy(), kept.numpy()[exp_i[0]])
        np.testing.assert_allclose(result.dists[b].numpy(), exp_d[0], rtol=1e-9, atol=1e-12)
    assert valid.gather(1, result.idx.reshape(2, -1)).all()


def test_knn_reference_valid_all_true_is_default():
    query, reference = _clouds(2, 20, 15, dtype=torch.float32, seed=7)
    a = knn_points(query, reference, k=4)
    b = knn_points(query, reference, k=4, reference_valid=torch.ones(2, 15, dtype=torch.bool))
    assert torch.equal(a.idx, b.idx)
    assert torch.equal(a.dists, b.dists)


def test_knn_reference_valid_fewer_than_k_pads_with_inf():
    query, reference = _clouds(2, 6, 10, seed=8)
    valid = torch.zeros(2, 10, dtype=torch.bool)
    valid[0, [2, 7]] = True  # 2 valid points for k = 3; none in the second element
    result = knn_points(query, reference, k=3, reference_valid=valid)
    assert set(result.idx[0, :, :2].flatten().tolist()) <= {2, 7}
    assert torch.isfinite(result.dists[0, :, :2]).all()
    assert torch.isinf(result.dists[0, :, 2]).all() and (result.idx[0, :, 2] == -1).all()
    assert torch.isinf(result.dists[1]).all() and (result.idx[1] == -1).all()


def test_knn_reference_valid_bad_shape_or_dtype_raises():
    query, reference = _clouds(2, 5, 6)
    with pytest.raises(ValueError, match="reference_valid"):
        knn_points(query, reference, reference_valid=torch.ones(2, 5, dtype=torch.bool))
    with pytest.raises(ValueError, match="reference_valid"):
        knn_points(query, reference, reference_valid=torch.ones(2, 6))


@pytest.mark.parametrize("k", [1, 4])
def test_tree_and_brute_agree_with_masks_and_padding(k):
    gen = torch.Generator().manual_seed(5)
    q, r = torch.rand(3, 50, 3, generator=gen), torch.rand(3, 70, 3, generator=gen)
    valid = torch.rand(3, 70, generator=gen) > 0.5
    valid[2] = False
    valid[2, :2] = True  # fewer than k valid points in the last cloud when k = 4
    tree = knn_points(q, r, k, reference_valid=valid, method="tree")
    brute = knn_points(q, r, k, reference_valid=valid, method="brute")
    assert torch.equal(tree.idx, brute.idx)
    assert torch.allclose(tree.dists, brute.dists, atol=1e-5)


def test_tree_distances_carry_gradients():
    q = torch.rand(1, 20, 3, dtype=torch.float64, requires_grad=True)
    r = torch.rand(1, 30, 3, dtype=torch.float64)
    knn_points(q, r, 2, method="tree").dists.sum().backward()
    assert q.grad is not None and q.grad.abs().sum() > 0


def test_unknown_method_raises():
    with pytest.raises(ValueError, match="auto, tree or brute"):
        knn_points(torch.rand(1, 4, 3), torch.rand(1, 4, 3), method="ball")


def test_the_nearest_field_finds_a_point_close_to_the_nearest():
    """Inside the box each query's point is at most 3.5 cells farther than the nearest (the
    cell centre's nearest occupied cell, and the first point in it), typically a fraction
    of a cell; a query outside the box takes the boundary."""
    rng = np.random.default_rng(3)
    cloud = rng.uniform(-1, 1, (2000, 3)) * [4, 4, 0.2]  # a slab: most voxels empty
    queries = rng.uniform(-5, 5, (5000, 3))
    cell = 0.1
    field = NearestField(cloud, cell, margin=1.0)
    found_d, found_i = field.query(queries)
    exact_d, _ = cloud_tree(cloud).query(queries, k=1)
    np.testing.assert_allclose(found_d, np.linalg.norm(cloud[found_i] - queries, axis=1))
    low, high = cloud.min(0) - 1.0, cloud.max(0) + 1.0
    inside = ((queries >= low) & (queries < high)).all(1)
    assert 0.2 < inside.mean() < 0.3
    excess = found_d[inside] - exact_d[inside]
    assert excess.max() <= 3.5 * cell and np.median(excess) < 0.25 * cell
    assert 0 < np.mean(excess > 0) < 0.5  # approximate, but mostly exact
    far = np.array([[40.0, 0, 0]])  # outside: the boundary voxel's point, not the nearest
    assert field.query(far)[0][0] >= cloud_tree(cloud).query(far, k=1)[0][0]
    assert nearest_field_cells(cloud, cell, 1.0) == int(np.prod(field.shape))
    with pytest.raises(ValueError, match="k=1"):
        field.query(queries, k=2)


def test_the_nearest_field_keeps_the_first_point_of_a_voxel_and_refuses_bad_input():
    cloud = np.array([[0.0, 0, 0], [0.01, 0.02, 0.0], [3, 3, 3], [3.01, 3, 3]])
    field = NearestField(cloud, 0.1, margin=0.5)
    assert field.query(np.array([[0.02, 0.01, 0.0], [2.9, 3, 3]]))[1].tolist() == [0, 2]
    with pytest.raises(ValueError, match="P >= 1"):
        NearestField(np.zeros((0, 3)), 0.1, 0.5)
    with pytest.raises(ValueError, match="margin >= 0"):
        NearestField(cloud, 0.1, -1.0)
    with pytest.raises(ValueError, match="cell > 0"):
        NearestField(cloud, 0.0, 1.0)

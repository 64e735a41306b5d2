"""Farthest point sampling."""

from __future__ import annotations

import numpy as np

from masknet.geometry.sampling import PRESAMPLE, farthest_point_sample, grid_subset


def test_small_clouds_are_kept_whole():
    points = np.random.default_rng(0).normal(size=(50, 3))
    result = farthest_point_sample(points, 100)
    np.testing.assert_array_equal(result.indices, np.arange(50))
    assert result.radius == 0.0


def test_keeps_max_points_and_covers_the_cloud():
    points = np.random.default_rng(1).uniform(size=(800, 3))  # FPS of every point
    result = farthest_point_sample(points, 200)
    assert len(result.indices) == 200 == len(set(result.indices.tolist()))
    kept = points[result.indices]
    nearest = np.sqrt(((points[:, None] - kept[None]) ** 2).sum(-1)).min(1)
    np.testing.assert_allclose(nearest.max(), result.radius, rtol=1e-5)
    # Evenly spread: the covering radius beats a random subset's by a clear margin.
    random = points[np.random.default_rng(2).choice(800, 200, replace=False)]
    random_radius = np.sqrt(((points[:, None] - random[None]) ** 2).sum(-1)).min(1).max()
    assert result.radius < 0.8 * random_radius


def test_min_spacing_stops_early_so_a_half_cloud_keeps_about_half():
    points = np.random.default_rng(3).uniform(-1, 1, size=(20000, 3))
    full = farthest_point_sample(points, 512)
    half = farthest_point_sample(points[points[:, 0] > 0], 512, min_spacing=full.radius)
    assert full.radius > 0 and half.radius <= full.radius
    assert 0.35 * 512 < len(half.indices) < 0.75 * 512


def test_deterministic():
    points = np.random.default_rng(4).normal(size=(3000, 3))
    a, b = farthest_point_sample(points, 64), farthest_point_sample(points, 64)
    np.testing.assert_array_equal(a.indices, b.indices)


def _reference_fps(points: np.ndarray, k: int) -> list[int]:
    chosen, nearest = [0], np.full(len(points), np.inf)
    while len(chosen) < k:
        nearest = np.minimum(nearest, ((points - points[chosen[-1]]) ** 2).sum(1))
        chosen.append(int(nearest.argmax()))
    return chosen


def test_matches_exact_fps_order_and_reports_the_kept_set_radius_when_stopping_early():
    points = np.random.default_rng(5).normal(size=(2000, 3))
    result = farthest_point_sample(points, 500)  # 4 x 500 points: exact FPS of every point
    assert result.indices.tolist() == _reference_fps(points, 500)
    early = farthest_point_sample(points, 1000, min_spacing=0.5)
    assert early.indices.tolist() == result.indices[: len(early.indices)].tolist()
    assert len(early.indices) < 500
    kept = points[early.indices]
    covering = np.sqrt(((points[:, None] - kept[None]) ** 2).sum(-1)).min(1).max()
    np.testing.assert_allclose(early.radius, covering, rtol=1e-5)
    assert early.radius <= 0.5


def _crowded_square(rng: np.random.Generator, n: int) -> np.ndarray:
    """A 10 x 10 square, nine tenths of its n points within a disc of radius 0.5 at the
    centre (a scanner's crowd at its feet)."""
    crowd = rng.normal(0, 0.25, (9 * n // 10, 2))
    rest = rng.uniform(-5, 5, (n - len(crowd), 2))
    return np.c_[np.concatenate([crowd, rest]), np.zeros(n)]


def test_a_grid_subset_is_even_and_about_the_count_asked():
    rng = np.random.default_rng(0)
    square = _crowded_square(rng, 50_000)
    kept = grid_subset(square, 2_000)
    assert 1_800 <= len(kept) <= 2_000 and len(np.unique(kept)) == len(kept)
    near = np.linalg.norm(square[kept, :2], axis=1) < 1.0
    assert near.mean() < 0.1  # the disc is 3% of the area, and held 90% of the points
    assert (grid_subset(square[:500], 2_000) == np.arange(500)).all()
    assert (grid_subset(square, 2_000, seed=3) != kept).any()
    assert (grid_subset(square, 2_000) == kept).all()


def test_a_grid_subset_of_a_cloud_larger_than_the_presample_stays_even():
    rng = np.random.default_rng(0)
    square = _crowded_square(rng, 2 * PRESAMPLE)
    kept = grid_subset(square, 4_000)
    assert 3_600 <= len(kept) <= 4_000 and kept.max() < len(square)
    assert (np.linalg.norm(square[kept, :2], axis=1) < 1.0).mean() < 0.1


def test_spread_labels_gives_each_point_its_nearest_labelled_points_label():
    from masknet.geometry.sampling import nearest_of, spread_labels

    labelled = np.array([[0.0, 0, 0], [10.0, 0, 0]])
    points = np.array([[1.0, 0, 0], [9.0, 0, 0], [4.9, 0, 0], [5.1, 0, 0]])
    np.testing.assert_array_equal(nearest_of(points, labelled), [0, 1, 0, 1])
    np.testing.assert_array_equal(
        spread_labels(points, labelled, np.array([True, False])), [True, False, True, False]
    )
    rows = spread_labels(points, labelled, np.array([[1, 2], [3, 4]]))  # labels of any shape
    np.testing.assert_array_equal(rows, [[1, 2], [3, 4], [1, 2], [3, 4]])


def test_first_in_cells_keeps_the_first_point_of_each_cell():
    from masknet.geometry.sampling import first_in_cells

    points = np.array([[0.1, 0.1, 0.1], [0.2, 0.2, 0.2], [1.5, 0.1, 0.1], [-0.5, 0.0, 0.0]])
    kept = np.sort(first_in_cells(points, 1.0, origin=np.zeros(3)))
    np.testing.assert_array_equal(kept, [0, 2, 3])  # point 1 shares point 0's cell
    # From the points' own corner (-0.5, 0, 0): 0, 1 and 3 share a cell, 2 is alone.
    np.testing.assert_array_equal(np.sort(first_in_cells(points, 1.0)), [0, 2])


def test_first_in_cells_matches_a_sort_of_rows():
    """One int64 key per cell gives the cells that sorting the rows does, negative
    coordinates and an empty cloud included."""
    from masknet.geometry.sampling import first_in_cells

    points = np.random.default_rng(0).normal(size=(5000, 3)) * 3
    cells = np.floor(points / 0.5).astype(np.int64)
    _, expected = np.unique(cells, axis=0, return_index=True)
    kept = first_in_cells(points, 0.5, origin=np.zeros(3))
    np.testing.assert_array_equal(np.sort(kept), np.sort(expected))
    assert len(first_in_cells(np.empty((0, 3)), 0.5)) == 0
    # A grid too large for one int64 key falls back to the rows.
    far = np.array([[0.0, 0.0, 0.0], [1e7, 1e7, 1e7], [1e7, 1e7, 1e7 + 1e-5]])
    np.testing.assert_array_equal(np.sort(first_in_cells(far, 1e-6)), [0, 1, 2])


def test_an_early_stop_keeps_the_fewest_points_that_cover_within_the_spacing():
    """The stop is found by bisection on the gaps in FPS order: the kept points cover the
    cloud within ``min_spacing``, and one point fewer would not."""
    points = np.random.default_rng(6).uniform(-1, 1, size=(3000, 3))

    def covering(indices: np.ndarray) -> float:
        return float(np.sqrt(((points[:, None] - points[indices][None]) ** 2).sum(-1)).min(1).max())

    for spacing in (0.6, 0.35, 0.2):
        early = farthest_point_sample(points, 1000, min_spacing=spacing)
        assert covering(early.indices) <= spacing < covering(early.indices[:-1])
    unreached = farthest_point_sample(points, 1000, min_spacing=0.12)  # 1,000 cover 0.14
    assert len(unreached.indices) == 1000 and unreached.radius > 0.12


def test_a_large_cloud_is_sampled_from_a_random_pool_and_still_covers_it():
    """Over FPS_POOL times the points kept, FPS runs on a seeded random subset of that
    many: its points cover the whole cloud nearly as well as exact FPS, the same each call."""
    from masknet.geometry.sampling import FPS_POOL

    points = np.random.default_rng(7).uniform(-1, 1, size=(20000, 3))
    pooled = farthest_point_sample(points, 100)
    assert len(pooled.indices) == 100 and 20000 > FPS_POOL * 100
    assert not set(pooled.indices.tolist()) <= set(range(FPS_POOL * 100))  # from the whole cloud
    np.testing.assert_array_equal(pooled.indices, farthest_point_sample(points, 100).indices)

    def covering(indices: np.ndarray) -> float:
        return float(np.sqrt(((points[:, None] - points[indices][None]) ** 2).sum(-1)).min(1).max())

    exact = points[_reference_fps(points, 100)]
    exact_radius = float(np.sqrt(((points[:, None] - exact[None]) ** 2).sum(-1)).min(1).max())
    assert covering(pooled.indices) < 1.3 * exact_radius

"""Farthest point sampling."""

from __future__ import annotations

import numpy as np

from masknet.geometry.sampling import farthest_point_sample


def test_small_clouds_are_kept_whole():
    points = np.random.default_rng(0).normal(size=(50, 3))
    result = farthest_point_sample(points, 100)
    np.testing.assert_array_equal(result.indices, np.arange(50))
    assert result.radius == 0.0


def test_keeps_max_points_and_covers_the_cloud():
    points = np.random.default_rng(1).uniform(size=(5000, 3))
    result = farthest_point_sample(points, 200)
    assert len(result.indices) == 200 == len(set(result.indices.tolist()))
    kept = points[result.indices]
    nearest = np.sqrt(((points[:, None] - kept[None]) ** 2).sum(-1)).min(1)
    np.testing.assert_allclose(nearest.max(), result.radius, rtol=1e-5)
    # Evenly spread: the covering radius beats a random subset's by a clear margin.
    random = points[np.random.default_rng(2).choice(5000, 200, replace=False)]
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
    result = farthest_point_sample(points, 100)
    assert result.indices.tolist() == _reference_fps(points, 100)
    early = farthest_point_sample(points, 1000, min_spacing=0.5)
    assert result.indices.tolist() == early.indices[:100].tolist() and len(early.indices) < 1000
    kept = points[early.indices]
    covering = np.sqrt(((points[:, None] - kept[None]) ** 2).sum(-1)).min(1).max()
    np.testing.assert_allclose(early.radius, covering, rtol=1e-5)
    assert early.radius <= 0.5

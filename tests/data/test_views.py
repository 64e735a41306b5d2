"""Sensor-like view pairs: independent sampling, visibility, geometric masks, seeded."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from masknet.data.views import ViewConfig, hidden_point_removal, make_view_pairs, normalize_cloud


def _sphere(n: int, seed: int = 0) -> np.ndarray:
    v = np.random.default_rng(seed).standard_normal((n, 3))
    return (v / np.linalg.norm(v, axis=1, keepdims=True)).astype(np.float32)


def test_normalize_cloud_gives_unit_radius_about_the_box_centre():
    cloud = normalize_cloud(_sphere(500) * 250.0 + 1000.0)
    mid = (cloud.max(0) + cloud.min(0)) / 2
    assert np.allclose(mid, 0, atol=1e-5)
    assert np.linalg.norm(cloud, axis=1).max() == pytest.approx(1.0, abs=1e-5)


def test_hidden_point_removal_sees_the_near_half_of_a_sphere():
    cloud = _sphere(4000)
    visible = hidden_point_removal(cloud, np.array([10.0, 0.0, 0.0]))
    assert 0.35 < visible.mean() < 0.6
    # What is seen faces the viewpoint: the far side (x < -0.2) is hidden.
    assert not visible[cloud[:, 0] < -0.2].any()
    assert visible[cloud[:, 0] > 0.5].mean() > 0.9


def test_view_pairs_share_no_point_and_the_mask_matches_the_source():
    config = ViewConfig(template_points=256, noise_sigma=0.0)
    clouds = [_sphere(2048, seed) for seed in range(4)]
    pairs = make_view_pairs(clouds, config, np.random.default_rng(0))
    assert pairs.template.shape == (4, 256, 3) and pairs.source.shape == (4, 179, 3)
    assert pairs.mask.shape == (4, 256) and pairs.source_mask.all()
    for b in range(4):
        transform = pairs.transform[b].double().numpy()
        back = pairs.source[b].double().numpy() @ transform[:3, :3].T + transform[:3, 3]
        template = pairs.template[b].double().numpy()
        # Back in the template frame, the source lies on the cloud but shares no point.
        assert cKDTree(clouds[b]).query(back)[0].max() < 1e-5
        assert cKDTree(template).query(back)[0].min() > 1e-6
        # About keep_ratio of the template is seen, and the seen part is near the source.
        mask = pairs.mask[b].numpy()
        assert 0.6 < mask.mean() < 0.8
        near = cKDTree(back).query(template)[0]
        assert np.median(near[mask]) < 0.5 * np.median(near[~mask])


def test_view_pairs_are_seeded_and_noise_scales_with_sigma():
    clouds = [_sphere(2048, 3)]
    a = make_view_pairs(clouds, ViewConfig(template_points=256), np.random.default_rng(5))
    b = make_view_pairs(clouds, ViewConfig(template_points=256), np.random.default_rng(5))
    c = make_view_pairs(clouds, ViewConfig(template_points=256), np.random.default_rng(6))
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not np.array_equal(a.source, c.source)
    noisy = make_view_pairs(
        clouds, ViewConfig(template_points=256, noise_sigma=0.01), np.random.default_rng(5)
    )
    offset = (noisy.source - a.source).norm(dim=-1)
    assert 0.005 < float(offset.mean()) < 0.03


def test_view_pair_refuses_a_cloud_too_small_and_bad_settings():
    with pytest.raises(ValueError, match="needs 512 cloud points"):
        make_view_pairs([_sphere(300)], ViewConfig(template_points=256), np.random.default_rng(0))
    with pytest.raises(ValueError, match="keep_ratio"):
        ViewConfig(keep_ratio=0)
    with pytest.raises(ValueError, match="view_distance"):
        ViewConfig(view_distance=(0.5, 2.0))

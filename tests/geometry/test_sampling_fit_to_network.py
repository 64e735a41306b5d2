"""masknet.geometry.sampling.fit_to_network: large single pairs brought to the network's size, the
source at the template's spacing so that its size still reflects the overlap."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from masknet.errors import MaskNetError
from masknet.geometry.sampling import fit_to_network


def _ellipsoid(n: int, seed: int) -> np.ndarray:
    """n points uniform in direction on an ellipsoid with axes 1, 0.7, 0.5."""
    points = np.random.default_rng(seed).normal(size=(n, 3))
    return points / np.linalg.norm(points, axis=1, keepdims=True) * [1.0, 0.7, 0.5]


def _covering_radius(cloud: np.ndarray, kept: np.ndarray) -> float:
    """Largest distance from a point of ``cloud`` to its nearest kept point."""
    return float(cKDTree(cloud[kept]).query(cloud)[0].max())


def test_small_pairs_are_left_as_they_are():
    template, source = _ellipsoid(1000, 0)[None], _ellipsoid(700, 1)[None]
    for single in (True, False):
        t, s, t_idx, s_idx = fit_to_network(template, source, single, 1024)
        assert t is template and s is source  # not even copied
        assert t_idx is None and s_idx is None
    # exactly max_points is small enough
    t, s, t_idx, s_idx = fit_to_network(template, source, True, 1000)
    assert t is template and t_idx is None and s_idx is None


@pytest.mark.parametrize("cut", [-0.3, 0.0, 0.3])
def test_a_large_pair_keeps_its_overlap_share(cut):
    """A 4,000-point template and the part of it beyond x = cut as the source, moved: the
    template is sampled to max_points and the source at the template's spacing, so that the
    source keeps about its share of the template's surface.

    The independent expectation: the template points are spread evenly over the surface,
    so the share of them in the source is the source's share of the surface, and points
    sampled at one spacing on one surface number in proportion to its area. Measured
    (sampled source / max_points) / share: 1.018, 1.009, 0.949 for cut -0.3, 0, 0.3
    (shares 0.66, 0.50, 0.36); bound: within 12%."""
    template = _ellipsoid(4000, 2)  # 4 x 1024 or fewer: FPS over every point
    part = template[:, 0] > cut
    share = part.mean()
    rotation = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    source = template[part] @ rotation.T + [0.5, -1.0, 2.0]
    t, s, t_idx, s_idx = fit_to_network(template[None], source[None], True, 1024)

    assert t.shape == (1, 1024, 3) and len(np.unique(t_idx)) == 1024
    np.testing.assert_array_equal(t[0], template[t_idx])
    np.testing.assert_array_equal(s[0], source[s_idx])
    assert len(np.unique(s_idx)) == len(s_idx) <= 1024
    ratio = len(s_idx) / 1024 / share
    assert abs(ratio - 1) < 0.12, (ratio, share)
    # the source was sampled no coarser than the template (a KD-tree's covering radii);
    # and not much finer: its covering radius reached the template's within 5% (measured
    # at most 0.2% below)
    template_radius = _covering_radius(template, t_idx)
    source_radius = _covering_radius(source, s_idx)
    assert source_radius <= template_radius * (1 + 1e-6)
    assert source_radius > 0.95 * template_radius, (source_radius, template_radius)


def test_a_large_template_with_a_small_source_samples_both():
    """The source is sampled at the template's spacing even when it is under max_points:
    900 random points over the whole surface hold close neighbours that the template's
    spacing (1,024 even samples of the same surface) does not need, so they thin out
    (bound 800 kept)."""
    template = _ellipsoid(4000, 3)
    source = _ellipsoid(900, 4)
    _, s, t_idx, s_idx = fit_to_network(template[None], source[None], True, 1024)
    assert s_idx is not None and len(s_idx) < 800
    assert _covering_radius(source, s_idx) <= _covering_radius(template, t_idx) * (1 + 1e-6)


def test_a_large_batch_is_refused():
    template = np.stack([_ellipsoid(1500, 5), _ellipsoid(1500, 6)])
    source = np.stack([_ellipsoid(500, 7), _ellipsoid(500, 8)])
    with pytest.raises(
        MaskNetError,
        match=r"batched clouds must have at most max_points=1024 points "
        r"\(got template 1500, source 500\)",
    ):
        fit_to_network(template, source, False, 1024)
    # a large source alone is refused too
    with pytest.raises(MaskNetError, match=r"got template 500, source 1500"):
        fit_to_network(source, template, False, 1024)


@pytest.mark.parametrize("cut", [-0.3, 0.0, 0.3])
def test_a_pair_sampled_from_random_pools_keeps_its_overlap_share(cut):
    """Clouds of over 4 x 1,024 points are sampled from a random pool of 4,096: a 20,000-
    point template and its part beyond x = cut still keep points in proportion to their
    surfaces (bound: within 15%)."""
    template = _ellipsoid(20000, 5)
    part = template[:, 0] > cut
    _, _, _, s_idx = fit_to_network(template[None], template[part][None], True, 1024)
    ratio = len(s_idx) / 1024 / part.mean()
    assert abs(ratio - 1) < 0.15, (ratio, part.mean())

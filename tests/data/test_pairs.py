"""Tests for masknet.data.pairs: shapes, determinism and the ground truth of generated pairs."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.optimize import linprog
from scipy.spatial import cKDTree

from masknet.data.pairs import (
    PairConfig,
    Pairs,
    derive_seed,
    iterate_pairs,
    make_pairs,
    make_test_pairs,
)
from masknet.geometry import invert_transform, split_transform, transform_points
from masknet.geometry.se3 import rotation_angle


def _shapes(s: int, n: int, seed: int = 0) -> np.ndarray:
    """(s, n, 3) float32 random points inside the unit ball, no duplicates."""
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(s, n, 3))
    pts /= np.linalg.norm(pts, axis=-1, keepdims=True)
    pts *= rng.uniform(0.3, 1.0, size=(s, n, 1))
    return pts.astype(np.float32)


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


OFFICIAL = PairConfig(protocol="official")


@pytest.fixture(scope="module")
def shapes() -> np.ndarray:
    return _shapes(4, 100)


def test_paper_protocol_shapes(shapes):
    pairs = make_pairs(shapes, PairConfig(), _gen(0))
    assert isinstance(pairs, Pairs)
    assert pairs.template.shape == (4, 100, 3)
    assert pairs.source.shape == (4, 70, 3)
    assert pairs.mask.shape == (4, 100) and pairs.mask.dtype == torch.bool
    assert pairs.transform.shape == (4, 4, 4)
    assert pairs.source_mask.shape == (4, 70) and pairs.source_mask.all()
    assert pairs.template.dtype == pairs.source.dtype == pairs.transform.dtype == torch.float32
    assert (pairs.mask.sum(1) == 70).all()
    # The template is the input, unchanged.
    assert torch.equal(pairs.template, torch.from_numpy(shapes))


def test_keep_ratio_rounding():
    pairs = make_pairs(_shapes(2, 50), PairConfig(keep_ratio=0.5), _gen(1))
    assert pairs.source.shape == (2, 25, 3)
    assert (pairs.mask.sum(1) == 25).all()


def test_official_protocol_shapes():
    clouds = _shapes(2, 1024, seed=1)
    pairs = make_pairs(clouds, OFFICIAL, _gen(0))
    assert pairs.template.shape == (2, 1024, 3)
    assert pairs.source.shape == (2, 768, 3)
    assert (pairs.mask.sum(1) == 768).all()
    assert pairs.source_mask.shape == (2, 768)


def test_official_protocol_too_few_points_raises():
    with pytest.raises(ValueError, match="768"):
        make_pairs(_shapes(1, 100), OFFICIAL, _gen(0))


def test_bad_inputs_and_config_raise():
    with pytest.raises(ValueError):
        make_pairs(np.zeros((10, 3), np.float32), PairConfig(), _gen(0))
    with pytest.raises(ValueError):
        PairConfig(keep_ratio=0.0)
    with pytest.raises(ValueError):
        PairConfig(protocol="other")
    with pytest.raises(ValueError):
        PairConfig(outlier_target="both")
    with pytest.raises(ValueError):
        PairConfig(outlier_ratio=1.0)


@pytest.mark.parametrize("config", [PairConfig(), PairConfig(noise_sigma=0.01, outlier_ratio=0.1)])
def test_same_seed_same_pairs_different_seed_different(shapes, config):
    a = make_pairs(shapes, config, _gen(7))
    b = make_pairs(shapes, config, _gen(7))
    c = make_pairs(shapes, config, _gen(8))
    for x, y in zip(a, b, strict=True):
        assert torch.equal(x, y)
    assert not torch.equal(a.source, c.source)
    assert not torch.equal(a.mask, c.mask)
    assert not torch.equal(a.transform, c.transform)


def _assert_ground_truth(pairs: Pairs, tol: float = 1e-5) -> None:
    """transform(source) is exactly the set of masked template points."""
    aligned = transform_points(pairs.transform.double(), pairs.source.double())
    for b in range(pairs.template.shape[0]):
        tree = cKDTree(pairs.template[b].double().numpy())
        dist, idx = tree.query(aligned[b].numpy())
        assert dist.max() < tol
        assert len(np.unique(idx)) == len(idx)  # a bijection onto ...
        expected = np.flatnonzero(pairs.mask[b].numpy())
        np.testing.assert_array_equal(np.sort(idx), expected)  # ... the masked points


def test_ground_truth_paper(shapes):
    _assert_ground_truth(make_pairs(shapes, PairConfig(), _gen(2)))


def test_ground_truth_paper_large_motion(shapes):
    config = PairConfig(max_angle_deg=180.0, max_translation=3.0)
    _assert_ground_truth(make_pairs(shapes, config, _gen(3)))


def test_ground_truth_official():
    _assert_ground_truth(make_pairs(_shapes(2, 1024, seed=2), OFFICIAL, _gen(4)))


def test_source_is_shuffled(shapes):
    """Source order does not follow template order."""
    pairs = make_pairs(shapes, PairConfig(), _gen(5))
    aligned = transform_points(pairs.transform, pairs.source)
    idx = cKDTree(pairs.template[0].numpy()).query(aligned[0].numpy())[1]
    assert not np.all(np.diff(idx) > 0)


@pytest.mark.parametrize("max_angle", [10.0, 45.0])
def test_paper_rotation_and_translation_ranges(max_angle):
    clouds = _shapes(256, 20, seed=3)
    config = PairConfig(max_angle_deg=max_angle, max_translation=0.5)
    pairs = make_pairs(clouds, config, _gen(6))
    motion = invert_transform(pairs.transform.double())  # template frame -> source frame
    rot, trans = split_transform(motion)
    deg = torch.rad2deg(rotation_angle(rot))
    assert deg.max() <= max_angle + 1e-3
    assert deg.max() > 0.8 * max_angle  # the range is used
    assert trans.abs().max() <= 0.5 + 1e-6
    assert trans.abs().max() > 0.4
    # Transform and motion have the same rotation angle.
    torch.testing.assert_close(
        rotation_angle(pairs.transform.double()[:, :3, :3]), rotation_angle(rot)
    )


def test_official_twist_magnitude_bound():
    clouds = _shapes(64, 768, seed=4)
    pairs = make_pairs(clouds, OFFICIAL, _gen(7))
    angle = rotation_angle(pairs.transform.double()[:, :3, :3])
    assert angle.max() <= 0.8 + 1e-5
    assert angle.max() > 0.3


def test_noise_is_clipped(shapes):
    config = PairConfig(noise_sigma=1.0, noise_clip=0.05)
    noisy = make_pairs(shapes, config, _gen(9))
    clean = make_pairs(shapes, PairConfig(noise_clip=0.05), _gen(9))
    assert torch.equal(noisy.mask, clean.mask)
    assert torch.equal(noisy.transform, clean.transform)
    diff = (noisy.source - clean.source).abs()
    assert diff.max() <= 0.05 + 1e-6
    assert diff.max() >= 0.05 - 1e-6  # sigma >> clip: the clip is reached
    assert (diff > 0).float().mean() > 0.99


def test_small_noise_is_not_all_clipped(shapes):
    config = PairConfig(noise_sigma=0.001, noise_clip=0.05)
    noisy = make_pairs(shapes, config, _gen(10))
    clean = make_pairs(shapes, PairConfig(), _gen(10))
    diff = noisy.source - clean.source
    assert 0.0005 < diff.std() < 0.002
    assert diff.abs().max() < 0.05


def test_source_outliers():
    clouds = _shapes(3, 100, seed=5)
    config = PairConfig(outlier_ratio=0.2)
    pairs = make_pairs(clouds, config, _gen(11))
    m = 70
    extra = round(0.2 * m)
    assert pairs.source.shape == (3, m + extra, 3)
    assert pairs.source_mask.shape == (3, m + extra)
    assert pairs.source_mask[:, :m].all() and not pairs.source_mask[:, m:].any()
    assert pairs.template.shape == (3, 100, 3)
    assert (pairs.mask.sum(1) == m).all()
    inliers, outliers = pairs.source[:, :m], pairs.source[:, m:]
    lo, hi = inliers.amin(1, keepdim=True), inliers.amax(1, keepdim=True)
    assert ((outliers >= lo - 1e-6) & (outliers <= hi + 1e-6)).all()
    # The inliers still carry the ground truth.
    inlier_pairs = pairs._replace(source=inliers, source_mask=pairs.source_mask[:, :m])
    _assert_ground_truth(inlier_pairs)


def test_template_outliers():
    clouds = _shapes(3, 100, seed=6)
    config = PairConfig(outlier_ratio=0.1, outlier_target="template")
    pairs = make_pairs(clouds, config, _gen(12))
    assert pairs.template.shape == (3, 110, 3)
    assert pairs.mask.shape == (3, 110)
    assert not pairs.mask[:, 100:].any()
    assert (pairs.mask.sum(1) == 70).all()
    assert pairs.source.shape == (3, 70, 3) and pairs.source_mask.all()
    assert torch.equal(pairs.template[:, :100], torch.from_numpy(clouds))
    t = torch.from_numpy(clouds)
    lo, hi = t.amin(1, keepdim=True), t.amax(1, keepdim=True)
    extra = pairs.template[:, 100:]
    assert ((extra >= lo - 1e-6) & (extra <= hi + 1e-6)).all()


def test_paper_partial_is_a_half_space_cut():
    """With a far viewpoint the kept points are those furthest along one direction.

    Checked by linear programming: find a unit-ish direction d and offset c with
    kept.d >= c + s and dropped.d <= c - s, maximising s. A viewpoint at distance
    500 makes the cut a plane up to |x|^2 / 1000 <= 1e-3, so s >= -2e-3; a random
    subset would be far from separable.
    """
    clouds = _shapes(3, 150, seed=7)
    pairs = make_pairs(clouds, PairConfig(view_distance=500.0), _gen(13))
    for b in range(3):
        x = pairs.template[b].double().numpy()
        kept, dropped = x[pairs.mask[b].numpy()], x[~pairs.mask[b].numpy()]
        assert _separation_margin(kept, dropped) > -2e-3
    rng = np.random.default_rng(0)
    random_mask = np.zeros(150, bool)
    random_mask[rng.choice(150, 105, replace=False)] = True
    x = pairs.template[0].double().numpy()
    assert _separation_margin(x[random_mask], x[~random_mask]) < -0.05


def _separation_margin(kept: np.ndarray, dropped: np.ndarray) -> float:
    """Largest s with kept.d >= c + s, dropped.d <= c - s, |d| normalised; s < 0 if inseparable.

    The scale of d is fixed by d.d0 = 1, where d0 points from the dropped centroid to
    the kept centroid (the true view direction has a positive component along it).
    """
    d0 = kept.mean(0) - dropped.mean(0)
    # Variables: d (3), c, s. Maximise s.
    a_kept = np.hstack([-kept, np.ones((len(kept), 1)), np.ones((len(kept), 1))])
    a_drop = np.hstack([dropped, -np.ones((len(dropped), 1)), np.ones((len(dropped), 1))])
    res = linprog(
        c=[0, 0, 0, 0, -1],
        A_ub=np.vstack([a_kept, a_drop]),
        b_ub=np.zeros(len(kept) + len(dropped)),
        A_eq=np.array([[*d0, 0, 0]]),
        b_eq=[1.0],
        bounds=[(-100, 100)] * 3 + [(None, None), (-100, 100)],
        method="highs",
    )
    assert res.status == 0
    return float(res.x[4] / np.linalg.norm(res.x[:3]))


def test_iterate_pairs_deterministic_per_epoch():
    points = _shapes(10, 60, seed=8)
    config = PairConfig(noise_sigma=0.01)
    a = list(iterate_pairs(points, config, batch_size=4, seed=3, epoch=0))
    b = list(iterate_pairs(points, config, batch_size=4, seed=3, epoch=0))
    c = list(iterate_pairs(points, config, batch_size=4, seed=3, epoch=1))
    d = list(iterate_pairs(points, config, batch_size=4, seed=4, epoch=0))
    assert [p.template.shape[0] for p in a] == [4, 4, 2]
    for pa, pb in zip(a, b, strict=True):
        for x, y in zip(pa, pb, strict=True):
            assert torch.equal(x, y)
    assert not torch.equal(a[0].source, c[0].source)
    assert not torch.equal(a[0].source, d[0].source)
    # Every shape appears exactly once per epoch.
    seen = torch.cat([p.template for p in a]).numpy()
    order = sorted(int(np.flatnonzero((points == s).all(axis=(1, 2)))[0]) for s in seen)
    assert order == list(range(10))


def test_iterate_pairs_drop_last_and_no_shuffle():
    points = _shapes(10, 40, seed=9)
    batches = list(
        iterate_pairs(points, PairConfig(), batch_size=4, seed=0, shuffle=False, drop_last=True)
    )
    assert [p.template.shape[0] for p in batches] == [4, 4]
    assert torch.equal(torch.cat([p.template for p in batches]), torch.from_numpy(points[:8]))


def test_iterate_pairs_num_points_subsampling():
    points = _shapes(6, 80, seed=10)
    batches = list(
        iterate_pairs(points, PairConfig(), batch_size=3, seed=1, num_points=50, shuffle=False)
    )
    assert len(batches) == 2
    for i, p in enumerate(batches):
        assert p.template.shape == (3, 50, 3)
        assert p.source.shape == (3, 35, 3)
        assert p.mask.shape == (3, 50)
        for j in range(3):
            full = points[3 * i + j]
            sub = p.template[j].numpy()
            # A subset of distinct points of the right shape.
            dist, idx = cKDTree(full).query(sub)
            assert dist.max() == 0 and len(np.unique(idx)) == 50
        _assert_ground_truth(p)
    other = next(
        iterate_pairs(
            points, PairConfig(), batch_size=3, seed=1, epoch=1, num_points=50, shuffle=False
        )
    )
    assert not torch.equal(other.template, batches[0].template)  # drawn anew each epoch


def test_make_test_pairs_distinct_shapes_and_reproducible():
    points = _shapes(12, 40, seed=11)
    config = PairConfig()
    a = make_test_pairs(points, num_pairs=10, config=config, seed=5, batch_size=4)
    b = make_test_pairs(points, num_pairs=10, config=config, seed=5, batch_size=4)
    c = make_test_pairs(points, num_pairs=10, config=config, seed=6, batch_size=4)
    assert a.template.shape == (10, 40, 3) and a.source.shape == (10, 28, 3)
    for x, y in zip(a, b, strict=True):
        assert torch.equal(x, y)
    assert not torch.equal(a.source, c.source)
    rows = a.template.reshape(10, -1).numpy()
    assert len(np.unique(rows, axis=0)) == 10
    _assert_ground_truth(a)


def test_make_test_pairs_cycles_when_more_pairs_than_shapes():
    points = _shapes(3, 30, seed=12)
    pairs = make_test_pairs(points, num_pairs=7, config=PairConfig(), seed=0)
    assert pairs.template.shape == (7, 30, 3)
    rows = pairs.template.reshape(7, -1).numpy()
    assert len(np.unique(rows, axis=0)) == 3
    assert len(np.unique(rows[:3], axis=0)) == 3  # the first pass uses each shape once


def test_derive_seed_stable_and_distinct():
    assert derive_seed(1, 2) == derive_seed(1, 2)
    assert derive_seed(1, 2) != derive_seed(2, 1)
    # The seeds iterate_pairs uses: order (seed, epoch, 0) and batches (seed, epoch, i + 1).
    used = {derive_seed(s, e, i) for s in (0, 1) for e in (0, 1, 2) for i in range(4)}
    assert len(used) == 2 * 3 * 4
    assert 0 <= derive_seed(123, 4) < 2**63


def test_config_to_dict_round_trip():
    config = PairConfig(noise_sigma=0.01, protocol="official")
    assert PairConfig(**config.to_dict()) == config


def test_sample_pair_is_one_seeded_test_pair_of_the_bundled_sample():
    from masknet.data import bundled_sample_path, load_modelnet40, sample_pair

    template, source, truth = sample_pair()
    assert template.dtype == source.dtype == truth.dtype == np.float64
    assert template.shape == (1024, 3) and source.shape == (717, 3) and truth.shape == (4, 4)
    shapes = load_modelnet40(bundled_sample_path(), "test").points[:1]
    pair = make_test_pairs(shapes, 1, PairConfig(), seed=3)
    np.testing.assert_array_equal(source, pair.source[0].double().numpy())
    # The truth moves the source onto template points.
    moved = source @ truth[:3, :3].T + truth[:3, 3]
    assert cKDTree(template).query(moved)[0].max() < 1e-5
    noisy = sample_pair(seed=4, config=PairConfig(outlier_ratio=0.1))[1]
    assert len(noisy) > len(source) * 0.9 and not np.array_equal(noisy[:10], source[:10])

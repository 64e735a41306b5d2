"""masknet.registration.terms.validation: register's argument checks, the clouds as float64
batches, rigid transforms, and the rows kept by drop_nonfinite."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from masknet.errors import MaskNetError
from masknet.registration.terms.validation import (
    as_numpy_batch,
    as_rigid_transforms,
    check_arguments,
    finite_rows,
    spread_rows,
)

# method, iterations, k, threshold, use_mask, init, refine_iterations, max_points
_GOOD = {
    "method": "icp",
    "iterations": 1,
    "k": None,
    "threshold": None,
    "use_mask": True,
    "init": "centroid",
    "refine_iterations": 0,
    "max_points": 1024,
}


def _check(**changes):
    check_arguments(**{**_GOOD, **changes})


def test_good_arguments_pass():
    _check()
    # numpy integers are integers; the lowest legal values pass
    _check(iterations=np.int64(2), refine_iterations=np.int32(0), max_points=3, k=np.int64(1))
    _check(threshold=0.5)
    _check(use_mask=False, init="identity", method="open3d-fgr")


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"method": "ndt"}, r"unknown registration method 'ndt'; choose from \('auto', 'icp'"),
        ({"iterations": 0}, "iterations must be an integer >= 1, got 0"),
        ({"iterations": True}, "iterations must be an integer >= 1, got True"),
        ({"iterations": 2.0}, r"iterations must be an integer >= 1, got 2\.0"),
        ({"refine_iterations": -1}, "refine_iterations must be an integer >= 0, got -1"),
        ({"refine_iterations": False}, "refine_iterations must be an integer >= 0, got False"),
        ({"max_points": 2}, "max_points must be an integer >= 3, got 2"),
        ({"init": "ransac"}, r"unknown init 'ransac'; choose from \('centroid', 'identity'\)"),
        ({"k": 10, "threshold": 0.5}, "give either k or mask_threshold, not both"),
        ({"k": 0}, "k must be an integer >= 1, got 0"),
        ({"k": True}, "k must be an integer >= 1, got True"),
        ({"k": 5.0}, r"k must be an integer >= 1, got 5\.0"),
        ({"k": 10, "use_mask": False}, "k and mask_threshold select MaskNet's inliers"),
        ({"threshold": 0.5, "use_mask": False}, "they need use_mask=True"),
    ],
)
def test_bad_arguments_are_refused(changes, message):
    with pytest.raises(MaskNetError, match=message):
        _check(**changes)


def _cloud(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(n, 3)).astype(np.float32)


def test_as_numpy_batch_single_and_batch():
    template, source = _cloud(40, 0), _cloud(30, 1)
    t, s, single = as_numpy_batch(template, source)
    assert single is True
    assert t.dtype == s.dtype == np.float64
    assert t.shape == (1, 40, 3) and s.shape == (1, 30, 3)
    np.testing.assert_array_equal(t[0], template.astype(np.float64))  # values kept exactly
    np.testing.assert_array_equal(s[0], source.astype(np.float64))
    batch_t, batch_s = np.stack([template, template + 1]), np.stack([source, source - 1])
    t, s, single = as_numpy_batch(batch_t, batch_s)
    assert single is False and t.dtype == np.float64 and t.shape == (2, 40, 3)
    np.testing.assert_array_equal(s[1], (source - 1).astype(np.float64))


def test_as_numpy_batch_refusals():
    template, source = _cloud(40, 0), _cloud(30, 1)
    with pytest.raises(MaskNetError, match="batch sizes differ: template 2, source 3"):
        as_numpy_batch(np.stack([template] * 2), np.stack([source] * 3))
    with pytest.raises(MaskNetError, match=r"must both be \(N,3\) or \(B,N,3\)"):
        as_numpy_batch(template, source[None])
    bad = source.copy()
    bad[4] = np.nan
    # An array in Python: the hint is Python's, not the command line's --drop-nonfinite.
    with pytest.raises(
        MaskNetError,
        match=r"^source: 1 row contains NaN or inf; drop those rows first \(register takes "
        r"drop_nonfinite=True\)$",
    ):
        as_numpy_batch(template, bad)


def _rigid(seed: int) -> np.ndarray:
    tf = np.eye(4)
    tf[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    tf[:3, 3] = np.random.default_rng(seed).normal(size=3)
    return tf


def test_as_rigid_transforms_broadcasts_and_copies():
    tf = _rigid(0).astype(np.float32)
    out = as_rigid_transforms(tf, 3)
    assert out.shape == (3, 4, 4) and out.dtype == np.float64 and out.flags.writeable
    for b in range(3):
        np.testing.assert_array_equal(out[b], tf.astype(np.float64))
    out[0, 0, 3] = 99.0  # a copy: the pairs do not share memory, nor with the input
    assert out[1, 0, 3] != 99.0 and tf[0, 3] != 99.0
    batch = np.stack([_rigid(1), _rigid(2)])
    np.testing.assert_array_equal(as_rigid_transforms(batch, 2), batch)
    # orthonormal to float32 rounding passes (the check's tolerance is 1e-4)
    nearly = _rigid(3)
    nearly[:3, :3] += 1e-6
    np.testing.assert_array_equal(as_rigid_transforms(nearly, 1)[0], nearly)


def test_as_rigid_transforms_refusals():
    rigid = "transform must be rigid"
    scaled = _rigid(0)
    scaled[:3, :3] *= 1.01
    reflected = _rigid(0)
    reflected[:3, 0] *= -1  # orthonormal, determinant -1
    assert np.allclose(reflected[:3, :3] @ reflected[:3, :3].T, np.eye(3))
    projective = _rigid(0)
    projective[3] = [0.0, 0.0, 0.1, 1.0]
    sheared = _rigid(0)
    sheared[0, 1] += 1e-2
    for tf in (scaled, reflected, projective, sheared):
        with pytest.raises(MaskNetError, match=rigid):
            as_rigid_transforms(tf, 1)
    # one bad transform of a batch is enough
    with pytest.raises(MaskNetError, match=rigid):
        as_rigid_transforms(np.stack([_rigid(1), reflected]), 2)
    nan = _rigid(0)
    nan[1, 3] = np.nan
    with pytest.raises(MaskNetError, match=r"transform holds NaN or inf"):
        as_rigid_transforms(nan, 1)
    with pytest.raises(MaskNetError, match=r"\(4, 4\) or \(2, 4, 4\), got \(3, 4, 4\)"):
        as_rigid_transforms(np.stack([_rigid(0)] * 3), 2)
    with pytest.raises(MaskNetError, match=r"got \(3, 3\)"):
        as_rigid_transforms(np.eye(3), 1)


def test_finite_rows_drops_nonfinite_rows():
    template, source = _cloud(20, 0).astype(np.float64), _cloud(15, 1).astype(np.float64)
    template[[3, 7], [0, 2]] = [np.nan, np.inf]
    source[14, 1] = -np.inf
    t, s, t_rows, s_rows = finite_rows(template, source)
    expected_t = np.isfinite(template).all(1)
    expected_s = np.isfinite(source).all(1)
    assert expected_t.sum() == 18 and expected_s.sum() == 14
    np.testing.assert_array_equal(t_rows, expected_t)
    np.testing.assert_array_equal(s_rows, expected_s)
    np.testing.assert_array_equal(t, template[expected_t])
    np.testing.assert_array_equal(s, source[expected_s])
    with pytest.raises(MaskNetError, match="drop_nonfinite takes one pair"):
        finite_rows(template[None], source[None])
    # a cloud left with under 3 points is still refused
    few = np.full((5, 3), np.nan)
    few[:2] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]
    with pytest.raises(MaskNetError, match="template: only 2 point"):
        finite_rows(few, source)


def test_spread_rows_puts_the_mask_back_on_every_row():
    rows = np.array([True, False, True, True, False, True])
    mask = np.array([[True, False, False, True]])  # over the 4 kept rows
    spread = spread_rows(mask, rows)
    # kept rows 0, 2, 3, 5 take the mask in order; dropped rows 1 and 4 are False
    np.testing.assert_array_equal(spread, [[True, False, False, False, False, True]])
    assert spread.shape == (1, 6) and spread.dtype == bool
    assert spread_rows(None, rows) is None


def test_a_path_given_as_a_cloud_says_to_read_it_first():
    from masknet import register

    with pytest.raises(MaskNetError, match=r"source is a path \('scan.ply'\).*read_points"):
        register(np.random.default_rng(0).normal(size=(50, 3)), "scan.ply")

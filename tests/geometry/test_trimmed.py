"""masknet.geometry.trimmed: trimmed means of squared distances, with and without masks."""

from __future__ import annotations

import numpy as np

from masknet.geometry.trimmed import trimmed_fit, trimmed_mean, trimmed_order


def test_the_trimmed_mean_drops_the_largest_distances():
    d2 = np.array([[1.0, 2.0, 3.0, 100.0]])
    np.testing.assert_allclose(trimmed_mean(d2, 0.75), [2.0])
    np.testing.assert_allclose(trimmed_mean(d2, 1.0), [26.5])


def test_a_mask_limits_each_row_and_an_empty_row_is_inf():
    d2 = np.array([[1.0, 2.0, 3.0, 100.0], [5.0, 5.0, 5.0, 5.0]])
    valid = np.array([[True, True, False, True], [False, False, False, False]])
    ordered, keep = trimmed_order(d2, 0.5, valid)
    assert np.isinf(ordered[0, -1]) and keep.tolist() == [2, 1]  # round(0.5 * 3) = 2
    np.testing.assert_allclose(trimmed_mean(d2, 0.5, valid), [1.5, np.inf])


def test_the_trimmed_fit_of_a_cloud_to_itself_is_zero_and_outliers_are_trimmed():
    rng = np.random.default_rng(0)
    cloud = rng.normal(size=(1, 200, 3))
    assert trimmed_fit(cloud, cloud, 0.9)[0] == 0
    noisy = cloud.copy()
    noisy[0, :10] += 50.0  # 5% far away
    assert trimmed_fit(noisy, cloud, 0.9)[0] == 0
    assert trimmed_fit(noisy, cloud, 1.0)[0] > 100

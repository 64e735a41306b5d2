"""Tests for masknet.geometry.clouds: validated cloud batches and unit radius."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from masknet.errors import MaskNetError
from masknet.geometry import MIN_POINTS, as_cloud_batch, median_spacing, unit_radius
from masknet.geometry.clouds import centroid_radius, principal_turn_deg


def test_unit_radius():
    pts = torch.tensor([[[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 3.0, 0.0], [1.0, -1.0, 0.0]]])
    # Bounding-box centre (1, 1, 0); farthest point (1, -1, 0) or (1, 3, 0) at distance 2.
    torch.testing.assert_close(unit_radius(pts), torch.tensor([2.0]))


def test_centroid_radius_numpy_and_torch_alike():
    pts = np.array([[[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [0.0, 4.0, 0.0], [0.0, 0.0, 4.0]]])
    # Centroid (1, 1, 1): the corners (4, 0, 0) ... lie sqrt(9 + 1 + 1) from it.
    np.testing.assert_allclose(centroid_radius(pts), [np.sqrt(11.0)])
    torch.testing.assert_close(
        centroid_radius(torch.from_numpy(pts)), torch.tensor([11.0]).sqrt().double()
    )
    assert centroid_radius(torch.from_numpy(pts).float()).dtype == torch.float32


CLOUD = np.random.default_rng(0).random((2, 40, 3))  # usable clouds (3-D, no warning)


def test_as_cloud_batch_single_and_batched():
    t, s, single = as_cloud_batch(CLOUD[0], CLOUD[1, :20].astype(np.float64))
    assert single and t.shape == (1, 40, 3) and s.shape == (1, 20, 3)
    assert t.dtype == s.dtype == torch.float32
    np.testing.assert_allclose(t[0].numpy(), CLOUD[0], rtol=1e-7)  # values kept, as float32
    t, s, single = as_cloud_batch(CLOUD, CLOUD[:, :20])
    assert not single and t.shape == (2, 40, 3) and s.shape == (2, 20, 3)
    with pytest.raises(MaskNetError, match="source 1: all 20 points are identical"):
        as_cloud_batch(CLOUD, np.stack([CLOUD[0, :20], np.ones((20, 3))]))  # every pair checked


@pytest.mark.parametrize(
    ("template", "source", "match"),
    [
        (np.zeros((10, 2)), np.zeros((5, 2)), "3 columns"),
        (np.zeros((10, 3)), np.zeros((2, 5, 3)), "both be"),
        (np.zeros((2, 10, 3)), np.zeros((3, 5, 3)), "batch sizes"),
        (CLOUD[0], CLOUD[1, : MIN_POINTS - 1], "at least"),
        (np.full((10, 3), np.nan), np.zeros((5, 3)), "NaN"),
    ],
)
def test_as_cloud_batch_rejects_bad_clouds(template, source, match):
    with pytest.raises(MaskNetError, match=match):
        as_cloud_batch(template, source)


@pytest.mark.parametrize(
    "bad", [np.full((10, 3), "1.0"), np.ones((10, 3), dtype=bool), np.empty((10, 3), dtype=object)]
)
def test_non_numeric_clouds_are_one_clear_error(bad):
    with pytest.raises(MaskNetError, match="template: expected numbers, got an array of dtype"):
        as_cloud_batch(bad, np.ones((10, 3)))


def test_spacing_ignores_exact_duplicates():
    grid = np.stack(np.meshgrid(*[np.arange(10.0)] * 2, [0.0]), -1).reshape(-1, 3) * 0.5
    doubled = np.concatenate([grid, grid])  # every point twice, as merged scans have
    assert median_spacing(doubled) == 0.5
    assert median_spacing(np.zeros((5, 3))) == 0.0  # one repeated point


def test_spacing_is_the_median_distance_to_the_three_nearest_points():
    # A line at spacing 1 (inner neighbours at 1, 1 and 2): 1, a sanity check. A random
    # plane tells the two measures apart: well above the nearest-neighbour distance.
    line = np.stack([np.arange(50.0), np.zeros(50), np.zeros(50)], -1)
    assert median_spacing(line) == 1.0
    rng = np.random.default_rng(0)
    plane = np.concatenate([rng.random((2000, 2)), np.zeros((2000, 1))], 1)
    nearest = np.median(np.sort(np.linalg.norm(plane[:, None] - plane[None], axis=-1), 1)[:, 1])
    assert 1.3 < median_spacing(plane) / nearest < 1.6  # not the nearest neighbour's distance


def _about_z(degrees: float) -> np.ndarray:
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_principal_turn_reads_a_turn_of_distinct_axes_and_nothing_of_a_round_cloud():
    """Variances 9, 3 and 1 (every axis defined): a turn of 70 degrees about z moves the x
    and y axes by 70; 150 degrees reads 30 (axes have no sign); a round cloud reads 0, as
    does a turn about the one defined axis of an elongated cloud."""
    rng = np.random.default_rng(0)
    cloud = rng.normal(size=(4000, 3)) * [3.0, np.sqrt(3.0), 1.0]
    assert principal_turn_deg(cloud, cloud @ _about_z(70).T) == pytest.approx(70, abs=2)
    assert principal_turn_deg(cloud, cloud @ _about_z(150).T) == pytest.approx(30, abs=2)
    assert principal_turn_deg(cloud, cloud + 5.0) == pytest.approx(0, abs=1e-6)
    round_cloud = rng.normal(size=(4000, 3))
    assert principal_turn_deg(round_cloud, round_cloud @ _about_z(70).T) == 0.0
    rod = rng.normal(size=(4000, 3)) * [3.0, 1.0, 1.0]  # only x is defined
    assert principal_turn_deg(rod, rod @ _about_z(60).T) == pytest.approx(60, abs=3)
    rolled = rod @ np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]).T  # 90 deg about x
    assert principal_turn_deg(rod, rolled) == pytest.approx(0, abs=3)
    # A line's two zero variances are rounding noise: their axes stay undefined, so a
    # line against itself reshuffled reads 0 (with an absolute floor it read 11-79).
    line = np.outer(rng.normal(size=500), [1.0, 2.0, 3.0])
    for seed in range(5):
        shuffled = line[np.random.default_rng(seed).permutation(len(line))]
        assert principal_turn_deg(line, shuffled) == pytest.approx(0, abs=1e-3)

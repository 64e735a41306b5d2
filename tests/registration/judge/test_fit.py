"""The one fit module: Open3D's fitness, the pipelines' score, the overlap fit, the guard."""

import numpy as np
import pytest

from masknet.geometry.knn import cloud_tree
from masknet.registration.judge.arbiter import fits_worse
from masknet.registration.judge.fit import (
    FIT_SLACK,
    SCORE_TRUNCATION,
    RoundFits,
    inlier_fit,
    overlap_fit,
    pose_fit,
    pose_fits,
)


@pytest.fixture(scope="module")
def grid() -> np.ndarray:
    """A 10 x 10 x 10 grid of unit spacing: 1,000 points, median spacing 1."""
    axis = np.arange(10.0)
    return np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)


def shifted(points: np.ndarray, dx: float) -> np.ndarray:
    return points + [dx, 0.0, 0.0]


def test_inlier_fit_is_open3ds_measure(grid):
    quality = inlier_fit(grid[None], shifted(grid, 0.25)[None], max_correspondence_distance=0.5)
    assert quality.fitness[0] == 1.0
    assert quality.inlier_rmse[0] == pytest.approx(0.25)
    far = inlier_fit(grid[None], shifted(grid, 0.25)[None], max_correspondence_distance=0.2)
    assert far.fitness[0] == 0.0 and far.inlier_rmse[0] == 0.0  # none within: RMSE 0, as Open3D


def test_inlier_fit_defaults_to_spacings_of_the_template(grid):
    quality = inlier_fit(grid[None], shifted(grid, 1.4)[None])  # 1.5 spacings of 1
    assert quality.max_correspondence_distance[0] == pytest.approx(1.5)
    # Shifted 1.4 along x, the last layer lies 0.4 beyond the grid and the rest 0.4 from one.
    assert quality.fitness[0] == 1.0


def test_pose_fit_scores_a_perfect_fit_one_and_a_far_one_zero(grid):
    tree = cloud_tree(grid)
    assert pose_fit(tree, grid, np.eye(4), 0.5) == (1.0, 0.0, 1.0)
    far = np.eye(4)
    far[0, 3] = 100.0
    fit = pose_fit(tree, grid, far, 0.5)
    assert fit.fitness == 0.0 and fit.score == 0.0


def test_the_score_is_truncated(grid):
    """A point beyond SCORE_TRUNCATION cut-offs weighs as one at the cap, however far."""
    tree = cloud_tree(grid)
    near_cap, beyond = grid.copy(), grid.copy()
    near_cap[0] -= [SCORE_TRUNCATION * 0.5, 0, 0]  # exactly at the cap of a 0.5 cut-off
    beyond[0] -= [1000.0, 0, 0]
    a, b = (
        pose_fits(tree, near_cap, np.eye(4)[None], 0.5)[0],
        pose_fits(tree, beyond, np.eye(4)[None], 0.5)[0],
    )
    assert a.score == pytest.approx(b.score)
    assert a.score == pytest.approx(1 - 1 / len(grid))


def test_pose_fits_equals_pose_fit_pose_by_pose(grid):
    tree = cloud_tree(grid)
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, 0, 3] = [0.0, 0.3, 2.0]
    assert pose_fits(tree, grid, poses, 0.5) == [pose_fit(tree, grid, p, 0.5) for p in poses]


def test_the_guard_allows_fit_slack():
    assert not fits_worse(0.90 - FIT_SLACK / 2, 0.90)
    assert fits_worse(0.90 - 2 * FIT_SLACK, 0.90)
    np.testing.assert_array_equal(
        fits_worse(np.array([0.5, 0.89]), np.array([0.9, 0.9])), [True, False]
    )


def test_round_fits_keeps_a_start_that_fits_better(grid):
    fits = RoundFits(grid[None], grid[None])
    worse = np.eye(4)[None].copy()
    worse[0, 0, 3] = 3.0
    kept = fits.keep_no_worse(np.eye(4)[None], worse)
    np.testing.assert_array_equal(kept, np.eye(4)[None])
    # Once kept at its start, a pair stays there, even when a later round would fit.
    again = fits.keep_no_worse(np.eye(4)[None], np.eye(4)[None] + 0)
    assert fits.settled[0]
    np.testing.assert_array_equal(again, np.eye(4)[None])


def test_round_fits_takes_a_pose_that_fits_no_worse(grid):
    fits = RoundFits(grid[None], shifted(grid, 0.5)[None])
    better = np.eye(4)[None].copy()
    better[0, 0, 3] = -0.5
    np.testing.assert_array_equal(fits.keep_no_worse(np.eye(4)[None], better), better)


def test_overlap_fit_counts_within_the_near_band(grid):
    points = grid[:100].copy()
    points[:50] += [0.0, 0.0, 0.25]  # within 0.5 of the grid
    points[50:] += [0.0, 0.0, 100.0]  # nowhere near
    within_near, within, near = overlap_fit(cloud_tree(grid), points, 0.5)
    assert within_near == 1.0  # every point in the near band fits
    assert within == 0.5 and near == 0.5


def test_covered_points_are_the_template_points_near_the_moved_source():
    from masknet.registration.judge.fit import covered_points

    template = np.array([[0.0, 0, 0], [1, 0, 0], [5, 0, 0]])
    moved = np.array([[0.05, 0, 0], [1.2, 0, 0]])
    np.testing.assert_array_equal(covered_points(template, moved, 0.1), [True, False, False])
    np.testing.assert_array_equal(covered_points(template, moved, 0.25), [True, True, False])


def test_covered_points_is_exact_on_copied_points_and_covers_a_rescan():
    from masknet.registration.judge.fit import covered_points

    rng = np.random.default_rng(0)
    # A sphere's surface: a seen cap (z > 0.2) of the template, copied and re-sampled.
    template = rng.normal(size=(2000, 3))
    template /= np.linalg.norm(template, axis=1, keepdims=True)
    seen = template[:, 2] > 0.2
    copied = template[seen]
    limit = 0.15  # about 1.5 spacings of 2,000 points on the unit sphere
    np.testing.assert_array_equal(covered_points(template, copied, limit), seen)
    rescan = rng.normal(size=(1500, 3))
    rescan /= np.linalg.norm(rescan, axis=1, keepdims=True)
    rescan = rescan[rescan[:, 2] > 0.2]
    covered = covered_points(template, rescan, limit)
    assert (covered & seen).sum() / seen.sum() > 0.97  # the band covers between its points
    assert (covered & ~seen).sum() / covered.sum() < 0.08  # and stays near the cap
    # Each source point claims the template point under it, off by noise the band (three
    # times the median residual, here 0) does not reach.
    noisy = copied.copy()
    noisy[::3] += rng.normal(scale=0.001, size=noisy[::3].shape)
    np.testing.assert_array_equal(covered_points(template, noisy, limit), seen)
    # A source point beyond the limit claims nothing.
    far = np.vstack([copied, [[0.0, 0.0, -5.0]]])
    np.testing.assert_array_equal(covered_points(template, far, limit), seen)

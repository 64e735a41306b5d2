"""masknet.registration.solvers.backends.icp: the adapters of masknet's ICP (a numpy KD-tree loop
for one pair, batched torch float32 for a batch) and of Open3D's ICP, on ModelNet40 pairs
with a known transform: the template mask and the source mask select the points in use."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from masknet.errors import MaskNetError
from masknet.registration.solvers.backends.base import BackendRun
from masknet.registration.solvers.backends.icp import run_icp, run_open3d_icp
from masknet.registration.terms.options import ICPCriteria, Open3DICPOptions

pytestmark = pytest.mark.usefixtures("one_thread")

ICP = ICPCriteria(max_iterations=30)
OPEN3D = Open3DICPOptions(max_iterations=30)


@pytest.fixture(params=["icp", "open3d-icp"])
def backend(request):
    """(adapter, options) of each ICP; Open3D's only where it imports (the o3d fixture)."""
    if request.param == "icp":
        return run_icp, ICP
    request.getfixturevalue("o3d")
    return run_open3d_icp, OPEN3D


@pytest.fixture(scope="module")
def source_decoys(known_pairs):
    """The templates with every masked-out point replaced by a point of the unmoved
    source: a decoy right on top of a source point, which would pull ICP to the identity."""
    template = known_pairs.template.copy()
    for b in range(len(template)):
        out = np.flatnonzero(~known_pairs.mask[b])
        template[b, out] = known_pairs.source[b, : len(out)]
    return template


@pytest.fixture(scope="module")
def rejected(known_pairs):
    """A source mask rejecting 100 and 250 random points of the two pairs, and the sources
    with those points replaced by far outliers (5 units away, the shapes' radius is 1)."""
    rng = np.random.default_rng(1)
    source = known_pairs.source
    keep = np.ones(source.shape[:2], bool)
    for b, count in enumerate((100, 250)):
        keep[b, rng.choice(source.shape[1], count, replace=False)] = False
    far = source.copy()
    far[~keep] = 5.0 + rng.uniform(size=((~keep).sum(), 3))
    return keep, far


def test_run_icp_recovers_the_known_transform(known_pairs, pose_error):
    """Through the true mask, one pair at a time (numpy float64) and as a batch (torch
    float32). Measured: at most 3.2e-7 deg and 9.5e-9 (one pair), 8.9e-7 deg and 1.7e-8
    (batch); the pairs are turned by 2.4 and 0.76 deg. Bounds 1e-5 deg and 1e-6."""
    t, s, truth, mask = known_pairs
    singles = [run_icp(t[b : b + 1], s[b : b + 1], mask[b : b + 1], None, ICP) for b in range(2)]
    batch = run_icp(t, s, mask, None, ICP)
    for run in (*singles, batch):
        assert isinstance(run, BackendRun) and run.correspondence_inliers is None
        assert run.transform.dtype == np.float64
    single = np.concatenate([r.transform for r in singles])
    for estimate in (single, batch.transform):
        degrees, shift = pose_error(estimate, truth)
        assert degrees.max() < 1e-5 and shift.max() < 1e-6, (degrees, shift)
    for info in [r.info for r in singles] + [batch.info]:
        assert set(info) == {"converged", "fitness", "inlier_rmse", "iterations"}
        assert info["converged"].all() and (info["fitness"] == 1).all()
        assert ((info["iterations"] >= 1) & (info["iterations"] < 30)).all()  # measured 5, 6
        assert (info["inlier_rmse"] < 1e-6).all()  # measured 5.6e-8 at most


def test_masked_out_template_points_take_no_part(backend, known_pairs, source_decoys, pose_error):
    """Decoys in the masked-out slots leave the result exactly as it was; without the mask
    they pull the source towards where it lies (measured 0.85 and 1.8 deg off instead of
    3e-7; bound 0.5 deg)."""
    run, options = backend
    t, s, truth, mask = known_pairs
    for b in (slice(0, 1), slice(1, 2), slice(0, 2)):  # each pair, and the batch
        clean = run(t[b], s[b], mask[b], None, options)
        decoyed = run(source_decoys[b], s[b], mask[b], None, options)
        np.testing.assert_array_equal(decoyed.transform, clean.transform)
        np.testing.assert_array_equal(decoyed.info["fitness"], clean.info["fitness"])
    unmasked = run(source_decoys, s, None, None, options)
    assert pose_error(unmasked.transform, truth)[0].min() > 0.5


def test_rejected_source_points_take_no_part(backend, known_pairs, rejected, pose_error):
    """Far outliers in the rejected slots change nothing, one pair at a time, where the
    result is that of the kept points alone; without the source mask they ruin it
    (measured 17 and 118 deg; bound 10)."""
    run, options = backend
    t, _, truth, mask = known_pairs
    keep, far = rejected
    for b in range(2):
        one = slice(b, b + 1)
        outliers = run(t[one], far[one], mask[one], keep[one], options)
        clean = run(t[one], known_pairs.source[one], mask[one], keep[one], options)
        alone = run(t[one], far[one][:, keep[b]], mask[one], None, options)
        np.testing.assert_array_equal(outliers.transform, clean.transform)
        np.testing.assert_array_equal(outliers.transform, alone.transform)
        # fitness over the kept points only: every one of them fits
        assert outliers.info["fitness"][0] == alone.info["fitness"][0] == 1.0
    unmasked = run(t, far, mask, None, options)
    assert pose_error(unmasked.transform, truth)[0].min() > 10


def test_a_batch_equals_its_pairs(backend, known_pairs, rejected):
    """A batch with source masks keeping 617 and 467 points, and template masks of equal
    and then of unequal sizes (the torch branch gathers the first, masks the k-NN of the
    second), against each pair alone. Measured (masknet's ICP, float32 against float64):
    2.7e-8 on the transforms' entries, 0 on fitness; bound 1e-6 (float32 rounding at unit
    scale). Open3D's runs pair by pair: exactly equal."""
    run, options = backend
    t, _, _, mask = known_pairs
    keep, far = rejected
    unequal = mask.copy()
    unequal[0, np.flatnonzero(unequal[0])[:50]] = False
    for template_mask in (mask, unequal):
        batch = run(t, far, template_mask, keep, options)
        for b in range(2):
            one = slice(b, b + 1)
            single = run(t[one], far[one], template_mask[one], keep[one], options)
            np.testing.assert_allclose(batch.transform[b], single.transform[0], atol=1e-6, rtol=0)
            for key in ("fitness", "inlier_rmse"):
                np.testing.assert_allclose(batch.info[key][b], single.info[key][0], atol=1e-6)
            assert batch.info["iterations"][b] == single.info["iterations"][0]


def _kd_tree_fit(template, source, transform, cut):
    """Open3D's definitions, computed with scipy: the share of source points within ``cut``
    of the template once moved, and the RMS distance over those."""
    moved = source @ transform[:3, :3].T + transform[:3, 3]
    distance = cKDTree(template).query(moved)[0]
    inlier = distance <= cut
    return inlier.mean(), np.sqrt((distance[inlier] ** 2).mean())


def test_fitness_and_rmse_are_a_kd_tree_s(backend, known_pairs):
    """Sources with 72 far outliers added (9% of 789 points) and a 0.05 cut-off: fitness
    and inlier RMSE equal scipy's computation at the returned transform, over the template
    points in use (float64: to 1e-12; the float32 batch: measured 2.5e-8, bound 1e-6). The
    pair that converges fits exactly its view's points, 717 / 789."""
    run, _ = backend
    options = (
        ICPCriteria(max_iterations=30, max_correspondence_distance=0.05)
        if run is run_icp
        else Open3DICPOptions(max_iterations=30, max_correspondence_distance=0.05)
    )
    t, s, _, mask = known_pairs
    rng = np.random.default_rng(2)
    source = np.concatenate([s, rng.uniform(-1, 1, size=(2, 72, 3)) + [3.0, 0.0, 0.0]], 1)
    batch = run(t, source, mask, None, options)
    batch_atol = 1e-12 if run is run_open3d_icp else 1e-6  # Open3D's goes pair by pair
    for b in range(2):
        single = run(t[b : b + 1], source[b : b + 1], mask[b : b + 1], None, options)
        for result, i, atol in ((single, 0, 1e-12), (batch, b, batch_atol)):
            fitness, rmse = _kd_tree_fit(t[b][mask[b]], source[b], result.transform[i], 0.05)
            assert 0 < result.info["fitness"][i] < 1
            np.testing.assert_allclose(result.info["fitness"][i], fitness, atol=atol, rtol=0)
            np.testing.assert_allclose(result.info["inlier_rmse"][i], rmse, atol=atol, rtol=0)
    assert batch.info["fitness"][0] == pytest.approx(717 / 789, abs=1e-6)


def test_zero_iterations_evaluate_the_start(known_pairs):
    t, s, _, mask = known_pairs
    run = run_icp(t[:1], s[:1], mask[:1], None, ICPCriteria(max_iterations=0))
    np.testing.assert_array_equal(run.transform[0], np.eye(4))
    assert run.info["iterations"][0] == 0 and not run.info["converged"][0]
    fitness, rmse = _kd_tree_fit(t[0][mask[0]], s[0], np.eye(4), np.inf)
    assert fitness == run.info["fitness"][0] == 1.0
    np.testing.assert_allclose(run.info["inlier_rmse"][0], rmse, rtol=1e-12)


def test_open3d_icp_reports_no_iterations_and_no_convergence(o3d, known_pairs):
    t, s, _, mask = known_pairs
    run = run_open3d_icp(t, s, mask, None, OPEN3D)
    np.testing.assert_array_equal(run.info["iterations"], [-1, -1])
    np.testing.assert_array_equal(run.info["converged"], [False, False])


def test_a_bad_cloud_is_a_masknet_error(known_pairs):
    t, s, _, _ = known_pairs
    with pytest.raises(MaskNetError, match=r"^icp: expected template \(N,3\)"):
        run_icp(t[:1, :, :2], s[:1], None, None, ICP)

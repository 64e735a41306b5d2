"""Tests for masknet.registration.solvers.icp (one ICP: the numpy KD-tree branch for one pair, the
batched torch branch) and the Open3D backend."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.geometry import make_transform, so3_exp, transform_points
from masknet.registration.solvers.icp import ICPSolution, icp
from masknet.registration.solvers.open3d_icp import open3d_icp

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def shapes() -> np.ndarray:
    return load_modelnet40(bundled_sample_path()).points


def _pairs(shapes, num: int, seed: int, **config):
    config = {"max_angle_deg": 10, "max_translation": 0.1, **config}
    return make_test_pairs(shapes, num, PairConfig(**config), seed=seed)


def _angle(r1: torch.Tensor, r2: torch.Tensor) -> torch.Tensor:
    """Rotation angle between (..., 3, 3) rotations, accurate near zero (unlike arccos)."""
    return 2 * torch.arcsin(((r1 - r2).flatten(-2).norm(dim=-1) / 8**0.5).clamp(max=1))


def test_recovers_known_transform_on_full_overlap(shapes):
    pairs = _pairs(shapes, 4, seed=0, keep_ratio=1.0)
    sol = icp(
        pairs.template.double(), pairs.source.double(), max_iterations=50, relative_rmse=1e-12
    )
    assert isinstance(sol, ICPSolution)
    truth = pairs.transform.double()
    assert (_angle(sol.transform[:, :3, :3], truth[:, :3, :3]) < 1e-4).all()
    assert ((sol.transform[:, :3, 3] - truth[:, :3, 3]).norm(dim=-1) < 1e-4).all()
    assert sol.converged.all() and (sol.iterations < 50).all()
    assert torch.equal(sol.fitness, torch.ones(4, dtype=torch.float64))
    assert (sol.inlier_rmse < 1e-6).all()


def test_init_near_truth_is_refined(shapes):
    pairs = _pairs(shapes, 2, seed=1, keep_ratio=1.0, max_angle_deg=45, max_translation=1.0)
    truth = pairs.transform.double()
    g = torch.Generator().manual_seed(1)
    # 10 degrees about a random axis, plus a small shift, away from the truth.
    axis = torch.nn.functional.normalize(
        torch.randn(2, 3, generator=g, dtype=torch.float64), dim=-1
    )
    offset = make_transform(so3_exp(axis * np.radians(10)), torch.full((2, 3), 0.05).double())
    init = offset @ truth
    sol = icp(pairs.template.double(), pairs.source.double(), init=init, max_iterations=60)
    assert (_angle(sol.transform[:, :3, :3], truth[:, :3, :3]) < 1e-4).all()
    assert ((sol.transform[:, :3, 3] - truth[:, :3, 3]).norm(dim=-1) < 1e-4).all()


def test_shapes_and_dtypes(shapes):
    pairs = _pairs(shapes, 3, seed=2)
    sol = icp(pairs.template, pairs.source, max_iterations=3)
    assert sol.transform.shape == (3, 4, 4) and sol.transform.dtype == torch.float32
    assert sol.converged.shape == (3,) and sol.converged.dtype == torch.bool
    assert sol.iterations.shape == (3,) and sol.iterations.dtype == torch.int64
    assert sol.fitness.shape == (3,) and sol.fitness.dtype == torch.float32
    assert sol.inlier_rmse.shape == (3,) and sol.inlier_rmse.dtype == torch.float32
    assert (sol.iterations <= 3).all()
    sol64 = icp(pairs.template.double(), pairs.source.double(), max_iterations=3)
    torch.testing.assert_close(sol.transform.double(), sol64.transform, atol=1e-5, rtol=0)


def test_batched_equals_per_pair(shapes):
    pairs = _pairs(shapes, 3, seed=3, max_angle_deg=30, max_translation=0.3)
    src, tpl = pairs.source.double(), pairs.template.double()
    kwargs = {"max_iterations": 30, "relative_rmse": 5e-7, "max_correspondence_distance": 0.2}
    batched = icp(tpl, src, **kwargs)
    for b in range(3):
        single = icp(tpl[b : b + 1], src[b : b + 1], **kwargs)
        for got, want in zip(batched, single, strict=True):
            torch.testing.assert_close(got[b : b + 1], want, atol=1e-12, rtol=0)
    assert len(set(batched.iterations.tolist())) > 1  # pairs really stopped separately


def test_max_iterations_zero_evaluates_init(shapes):
    pairs = _pairs(shapes, 2, seed=4)
    init = pairs.transform.double()
    sol = icp(pairs.template.double(), pairs.source.double(), init=init, max_iterations=0)
    torch.testing.assert_close(sol.transform, init)
    assert (sol.iterations == 0).all() and not sol.converged.any()
    assert (sol.inlier_rmse < 1e-6).all()


def test_single_init_broadcasts(shapes):
    pairs = _pairs(shapes, 2, seed=5)
    src, tpl = pairs.source.double(), pairs.template.double()
    init = torch.eye(4, dtype=torch.float64)
    init[:3, 3] = 0.02
    a = icp(tpl, src, init=init, max_iterations=4)
    b = icp(tpl, src, init=init.expand(2, 4, 4), max_iterations=4)
    torch.testing.assert_close(a.transform, b.transform)


def test_template_valid_equals_icp_on_the_subset(shapes):
    pairs = _pairs(shapes, 2, seed=6)
    src, tpl = pairs.source.double(), pairs.template.double()
    g = torch.Generator().manual_seed(6)
    valid = torch.rand(tpl.shape[:2], generator=g) < 0.6
    masked = icp(tpl, src, template_valid=valid, max_iterations=8, max_correspondence_distance=0.3)
    for b in range(2):
        subset = tpl[b : b + 1, valid[b]]
        want = icp(subset, src[b : b + 1], max_iterations=8, max_correspondence_distance=0.3)
        for got, exp in zip(masked, want, strict=True):
            torch.testing.assert_close(got[b : b + 1], exp, atol=1e-12, rtol=0)
    # The masked-out points really are excluded: moving them far away changes nothing.
    far = torch.where(valid[..., None], tpl, tpl + 100.0)
    again = icp(far, src, template_valid=valid, max_iterations=8, max_correspondence_distance=0.3)
    torch.testing.assert_close(again.transform, masked.transform, atol=1e-12, rtol=0)


def test_equal_count_masks_take_the_gathered_path_with_the_same_result(shapes):
    """Top-k masks keep the same number of points in every pair; ICP then gathers them
    once. The result must equal the masked path (forced here by one pair with a
    different count) exactly."""
    pairs = _pairs(shapes, 3, seed=9)
    src, tpl = pairs.source.double(), pairs.template.double()
    g = torch.Generator().manual_seed(9)
    order = torch.rand(tpl.shape[:2], generator=g).argsort(1)
    valid = torch.zeros(tpl.shape[:2], dtype=torch.bool).scatter_(1, order[:, :600], True)
    gathered = icp(tpl, src, template_valid=valid, max_correspondence_distance=0.3)
    mixed = torch.cat([valid, torch.ones(1, valid.shape[1], dtype=torch.bool)])
    forced = icp(
        torch.cat([tpl, tpl[:1]]),
        torch.cat([src, src[:1]]),
        template_valid=mixed,
        max_correspondence_distance=0.3,
    )
    for got, exp in zip(gathered, forced, strict=True):
        torch.testing.assert_close(got, exp[:3], atol=1e-12, rtol=0)
    far = torch.where(valid[..., None], tpl, tpl + 100.0)
    again = icp(far, src, template_valid=valid, max_correspondence_distance=0.3)
    torch.testing.assert_close(again.transform, gathered.transform, atol=1e-12, rtol=0)


def test_no_valid_template_point_gives_identity(shapes):
    pairs = _pairs(shapes, 2, seed=7)
    valid = torch.ones(pairs.template.shape[:2], dtype=torch.bool)
    valid[1] = False
    sol = icp(pairs.template.double(), pairs.source.double(), template_valid=valid)
    torch.testing.assert_close(sol.transform[1], torch.eye(4, dtype=torch.float64))
    assert sol.fitness[1] == 0 and sol.inlier_rmse[1] == 0
    assert not sol.converged[1] and sol.iterations[1] == 0
    assert sol.fitness[0] == 1 and sol.iterations[0] > 0


def test_fitness_and_inlier_rmse_match_direct_computation(shapes):
    pairs = _pairs(shapes, 3, seed=8, max_angle_deg=20, max_translation=0.2)
    max_dist = 0.05
    sol = icp(
        pairs.template.double(),
        pairs.source.double(),
        max_iterations=5,
        max_correspondence_distance=max_dist,
    )
    moved = transform_points(sol.transform, pairs.source.double()).numpy()
    for b in range(3):
        d, _ = cKDTree(pairs.template[b].double().numpy()).query(moved[b])
        inlier = d <= max_dist
        assert 0 < inlier.mean() < 1  # the threshold really rejects some pairs
        np.testing.assert_allclose(sol.fitness[b].item(), inlier.mean(), rtol=1e-12)
        rmse = np.sqrt(np.mean(d[inlier] ** 2))
        np.testing.assert_allclose(sol.inlier_rmse[b].item(), rmse, rtol=1e-9)


def test_bad_arguments_raise(shapes):
    pairs = _pairs(shapes, 2, seed=9)
    src, tpl = pairs.source, pairs.template
    with pytest.raises(ValueError):
        icp(tpl[0], src[0])
    with pytest.raises(ValueError):
        icp(tpl[:1], src)
    with pytest.raises(ValueError, match="dtype"):
        icp(tpl.double(), src)
    with pytest.raises(ValueError, match="init"):
        icp(tpl, src, init=torch.eye(3))
    with pytest.raises(ValueError, match="max_correspondence_distance"):
        icp(tpl, src, max_correspondence_distance=0.0)
    with pytest.raises(ValueError, match="max_iterations"):
        icp(tpl, src, max_iterations=-1)


@pytest.mark.parametrize("max_dist", [None, 0.1])
def test_agrees_with_open3d_step_by_step(shapes, max_dist, o3d):
    """Same iterations, same correspondences, same closed-form step: same result."""
    pairs = _pairs(shapes, 2, seed=10, max_angle_deg=30, max_translation=0.3)
    src, tpl = pairs.source.double(), pairs.template.double()
    ours = icp(tpl, src, max_iterations=5, relative_rmse=0, max_correspondence_distance=max_dist)
    assert (ours.iterations == 5).all()
    for b in range(2):
        theirs = open3d_icp(
            tpl[b].numpy(),
            src[b].numpy(),
            max_iterations=5,
            max_correspondence_distance=max_dist,
            relative_fitness=0,
            relative_rmse=0,
        )
        torch.testing.assert_close(ours.transform[b], theirs.transform[0], atol=1e-10, rtol=0)
        torch.testing.assert_close(ours.fitness[b], theirs.fitness[0], atol=1e-12, rtol=0)
        torch.testing.assert_close(ours.inlier_rmse[b], theirs.inlier_rmse[0], atol=1e-10, rtol=0)


def test_agrees_with_open3d_when_converged(shapes, o3d):
    pairs = _pairs(shapes, 2, seed=11, keep_ratio=1.0)
    truth = pairs.transform.double()
    ours = icp(pairs.template.double(), pairs.source.double(), max_iterations=50)
    for b in range(2):
        theirs = open3d_icp(pairs.template[b].numpy(), pairs.source[b].numpy(), max_iterations=50)
        assert theirs.transform.shape == (1, 4, 4) and theirs.iterations.item() == -1
        torch.testing.assert_close(ours.transform[b], theirs.transform[0], atol=1e-6, rtol=0)
        assert _angle(theirs.transform[0, :3, :3], truth[b, :3, :3]) < 1e-4


def test_open3d_icp_empty_template_and_init(o3d):
    g = np.random.default_rng(0)
    source = g.normal(size=(30, 3))
    init = np.eye(4)
    init[:3, 3] = [0.1, 0.2, 0.3]
    sol = open3d_icp(np.empty((0, 3)), source, init=init)
    np.testing.assert_array_equal(sol.transform[0].numpy(), init)
    assert sol.fitness.item() == 0
    moved = source @ init[:3, :3].T + init[:3, 3]
    sol = open3d_icp(moved, source, init=init, max_iterations=1)  # already aligned
    np.testing.assert_allclose(sol.transform[0].numpy(), init, atol=1e-12)
    assert sol.fitness.item() == 1 and sol.inlier_rmse.item() < 1e-12
    with pytest.raises(ValueError, match="init"):
        open3d_icp(moved, source, init=np.eye(3))


def test_template_valid_must_be_bool(shapes):
    pairs = _pairs(shapes, 2, seed=10)
    ones = torch.ones(pairs.template.shape[:2], dtype=torch.int64)  # equal counts, wrong dtype
    with pytest.raises(ValueError, match="reference_valid must be a bool tensor"):
        icp(pairs.template.double(), pairs.source.double(), template_valid=ones)


def test_keyword_names_follow_the_template_source_order(shapes):
    pairs = _pairs(shapes, 2, seed=12)
    tpl, src = pairs.template.double(), pairs.source.double()
    positional = icp(tpl, src, max_iterations=3)
    keywords = icp(source=src, template=tpl, max_iterations=3)
    torch.testing.assert_close(positional.transform, keywords.transform, atol=0, rtol=0)


@pytest.mark.parametrize("distance", [None, 0.1])
def test_single_pair_kdtree_loop_matches_the_batched_icp(distance):
    rng = np.random.default_rng(4)
    template = rng.normal(size=(400, 3))
    angle = np.radians(12)
    rot = np.array(
        [[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]]
    )
    source = template[:300] @ rot.T + [0.05, -0.02, 0.03]
    options = {"max_iterations": 30, "max_correspondence_distance": distance}
    single = icp(template, source, **options)  # numpy: the KD-tree branch
    assert isinstance(single.transform, np.ndarray)
    batched = icp(torch.from_numpy(template)[None], torch.from_numpy(source)[None], **options)
    np.testing.assert_allclose(single.transform, batched.transform.numpy(), atol=1e-9)
    assert int(single.iterations[0]) == int(batched.iterations[0]) > 1
    assert bool(single.converged[0]) == bool(batched.converged[0])
    np.testing.assert_allclose(single.fitness, batched.fitness.numpy())
    np.testing.assert_allclose(single.inlier_rmse, batched.inlier_rmse.numpy(), atol=1e-9)


def test_rejected_source_points_take_no_part_in_a_batch():
    """A batch keeps one shape, so rejected source points stay in it: ``source_valid``
    must leave them out of the solve and the fitness, so that each pair of the batch
    registers exactly as its kept points alone do (they once were filled with repeats of
    kept points, which then counted twice)."""
    rng = np.random.default_rng(5)
    template = rng.normal(size=(2, 300, 3))
    angle = np.radians(8)
    rot = np.array(
        [[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]]
    )
    source = template[:, :200] @ rot.T + [0.05, -0.02, 0.03]
    source[:, :40] += rng.normal(scale=2.0, size=(2, 40, 3))  # outliers, rejected below
    keep = np.ones((2, 200), bool)
    keep[:, :40] = False
    keep[1, 40:70] = False  # another count in the second pair
    batched = icp(
        torch.from_numpy(template),
        torch.from_numpy(source),
        max_iterations=30,
        source_valid=torch.from_numpy(keep),
    )
    for b in range(2):
        alone = icp(template[b], source[b][keep[b]], max_iterations=30)
        np.testing.assert_allclose(batched.transform[b].numpy(), alone.transform[0], atol=1e-9)
        np.testing.assert_allclose(float(batched.fitness[b]), alone.fitness[0])
        np.testing.assert_allclose(float(batched.inlier_rmse[b]), alone.inlier_rmse[0], atol=1e-9)


# ---------------------------------------------------------------------- point-to-plane
def test_point_to_plane_converges_where_open3d_does(shapes, o3d):
    """Same pairs and normals: Open3D's point-to-plane ICP and ours settle on one pose."""
    from masknet.geometry.normals import estimate_normals

    pairs = _pairs(shapes, 2, seed=12, keep_ratio=1.0, max_angle_deg=5, max_translation=0.05)
    reg = o3d.pipelines.registration
    for b in range(2):
        template = pairs.template[b].double().numpy()
        source = pairs.source[b].double().numpy()
        normals = estimate_normals(template)[0]
        ours = icp(template, source, max_iterations=60, relative_rmse=0, template_normals=normals)
        target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(template))
        target.normals = o3d.utility.Vector3dVector(normals)
        moving = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source))
        theirs = reg.registration_icp(
            moving,
            target,
            10.0,
            np.eye(4),
            reg.TransformationEstimationPointToPlane(),
            reg.ICPConvergenceCriteria(1e-12, 1e-12, 60),
        ).transformation
        np.testing.assert_allclose(ours.transform[0], theirs, atol=1e-6)
        truth = pairs.transform[b].double().numpy()
        np.testing.assert_allclose(ours.transform[0], truth, atol=1e-6)  # a copied source


def test_point_to_plane_is_closer_than_point_to_point_on_a_resampled_surface():
    """A source sampled between the template's points: point-to-point pulls it onto them."""
    from masknet.geometry.normals import estimate_normals

    g = np.random.default_rng(3)
    u, v = g.uniform(-1, 1, (2, 4000))
    template = np.stack([u, v, 0.3 * np.sin(2 * u) * np.cos(2 * v)], 1)
    u, v = g.uniform(-0.7, 0.7, (2, 1500))  # re-sampled, a part of the surface
    surface = np.stack([u, v, 0.3 * np.sin(2 * u) * np.cos(2 * v)], 1)
    turn = make_transform(so3_exp(torch.tensor([[0.03, -0.02, 0.04]])), torch.zeros(1, 3))
    truth = turn[0].double().numpy()
    source = transform_points(np.linalg.inv(truth), surface)
    cut = 0.2
    plane = icp(
        template,
        source,
        max_iterations=30,
        max_correspondence_distance=cut,
        template_normals=estimate_normals(template)[0],
    )
    point = icp(template, source, max_iterations=30, max_correspondence_distance=cut)

    def off(solution) -> float:
        return float(
            np.linalg.norm(transform_points(solution.transform[0], source) - surface, axis=1).mean()
        )

    assert off(plane) < 0.5 * off(point)


def test_point_to_plane_refuses_bad_normals(shapes):
    template = shapes[0].astype(np.float64)
    with pytest.raises(ValueError, match="template_normals"):
        icp(template, template, template_normals=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="numpy"):
        icp(
            torch.from_numpy(template)[None],
            torch.from_numpy(template)[None],
            template_normals=np.zeros_like(template),
        )

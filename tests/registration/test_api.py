"""Tests for masknet.register (Mask-ICP and plain ICP, numpy in, numpy out)."""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

import masknet
import masknet._open3d
from masknet import MaskNet, MaskNetError, RegistrationResult, evaluate_registration, register
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.geometry.clouds import Frame, median_spacing
from masknet.io import require_open3d

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def pairs():
    shapes = load_modelnet40(bundled_sample_path()).points
    return make_test_pairs(shapes, 3, PairConfig(max_angle_deg=10, max_translation=0.1), seed=0)


@pytest.fixture(scope="module")
def full_pairs():
    shapes = load_modelnet40(bundled_sample_path()).points
    config = PairConfig(keep_ratio=1.0, max_angle_deg=10, max_translation=0.1)
    return make_test_pairs(shapes, 2, config, seed=1)


def _angle(r1: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """Rotation angle between (..., 3, 3) rotations, accurate near zero."""
    diff = np.linalg.norm((r1 - r2).reshape(*r1.shape[:-2], 9), axis=-1)
    return 2 * np.arcsin(np.minimum(diff / 8**0.5, 1))


def _open3d_or_skip():
    try:
        return require_open3d("these tests")
    except MaskNetError as exc:
        pytest.skip(str(exc))


def test_exported_from_the_package():
    assert masknet.register is register and masknet.RegistrationResult is RegistrationResult
    assert {"register", "RegistrationResult"} <= set(masknet.__all__)


def test_convention_source_moved_by_inverse_gives_transform(full_pairs):
    """source = template moved by T^-1, so register(template, source) must return T."""
    g = np.random.default_rng(0)
    template = full_pairs.template[0].double().numpy()
    angle = np.radians(8)
    axis = g.normal(size=3)
    axis /= np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rot = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    transform = np.eye(4)
    transform[:3, :3], transform[:3, 3] = rot, [0.05, -0.08, 0.03]
    # template = source @ R.T + t  <=>  source = (template - t) @ R
    source = (template - transform[:3, 3]) @ rot
    result = register(template, source, method="icp", use_mask=False, max_iterations=50)
    np.testing.assert_allclose(result.transform, transform, atol=1e-6)
    np.testing.assert_allclose(source @ result.R.T + result.t, template, atol=1e-6)


def test_plain_icp_recovers_pair_transform(full_pairs):
    result = register(
        full_pairs.template.numpy(),
        full_pairs.source.numpy(),
        method="icp",
        use_mask=False,
        max_iterations=50,
    )
    truth = full_pairs.transform.double().numpy()
    assert (_angle(result.R, truth[:, :3, :3]) < 1e-4).all()
    assert (np.linalg.norm(result.t - truth[:, :3, 3], axis=-1) < 1e-4).all()
    assert result.info["converged"].all()


def test_single_pair_shapes(pairs, small_masknet):
    template, source = pairs.template[0].numpy(), pairs.source[0].numpy()
    result = register(template, source, method="icp", model=small_masknet)
    assert isinstance(result, RegistrationResult)
    assert result.R.shape == (3, 3) and result.t.shape == (3,) and result.transform.shape == (4, 4)
    assert result.transform.dtype == np.float64
    np.testing.assert_array_equal(result.transform[:3, :3], result.R)
    np.testing.assert_array_equal(result.transform[:3, 3], result.t)
    np.testing.assert_array_equal(result.transform[3], [0, 0, 0, 1])
    assert result.mask.shape == (template.shape[0],) and result.mask.dtype == np.bool_
    assert len(result.rounds) == 1 and result.rounds[0].shape == (4, 4)
    for key in ("converged", "fitness", "inlier_rmse", "iterations"):
        assert np.ndim(result.info[key]) == 0, key
    np.testing.assert_allclose(np.linalg.det(result.R), 1.0, atol=1e-9)
    # The values: the mask is MaskNet's top-k, and the fit figures are Open3D's at the
    # pose returned, 1.5 template spacings, found here with a KD-tree.
    np.testing.assert_array_equal(result.mask, small_masknet.predict_mask(template, source))
    moved = source.astype(float) @ result.R.T + result.t
    distance, _ = cKDTree(template.astype(float)).query(moved)
    inlier = distance <= 1.5 * median_spacing(template.astype(float))
    assert 0 < result.info["fitness"] < 1  # a wrong-basin pose leaves some points off
    # 2 / M: the call's frame holds float32 values; a point at the cut-off may flip
    assert abs(result.info["fitness"] - inlier.mean()) <= 2 / len(source)
    np.testing.assert_allclose(
        result.info["inlier_rmse"], np.sqrt(np.mean(distance[inlier] ** 2)), rtol=1e-3
    )


def test_batch_shapes_and_equals_single(pairs, small_masknet):
    template, source = pairs.template.numpy(), pairs.source.numpy()
    b, n, _ = template.shape
    # The paper's loop: no source mask, so a batch and its pairs see the same points (a
    # batch fills rejected source slots with kept points to keep one shape).
    result = register(
        template, source, method="icp", model=small_masknet, iterations=2, refine_masks="network"
    )
    assert result.R.shape == (b, 3, 3) and result.t.shape == (b, 3)
    assert result.transform.shape == (b, 4, 4) and result.mask.shape == (b, n)
    assert len(result.rounds) == 2 and all(r.shape == (b, 4, 4) for r in result.rounds)
    for key in ("converged", "fitness", "inlier_rmse", "iterations"):
        assert result.info[key].shape == (b,), key
    one = register(
        template[1],
        source[1],
        method="icp",
        model=small_masknet,
        iterations=2,
        refine_masks="network",
    )
    # One frame per call: a batch's scale is its templates' mean radius, a pair's its own;
    # coordinates in the frame hold float32 values, so the two agree to that precision.
    np.testing.assert_allclose(one.transform, result.transform[1], atol=1e-6)
    np.testing.assert_array_equal(one.mask, result.mask[1])


@pytest.mark.parametrize("iterations", [1, 3])
def test_rounds_are_cumulative(pairs, small_masknet, iterations):
    template, source = pairs.template.numpy(), pairs.source.numpy()
    result = register(
        template, source, method="icp", model=small_masknet, iterations=iterations, max_iterations=3
    )
    assert len(result.rounds) == iterations
    np.testing.assert_array_equal(result.rounds[-1], result.transform)
    # Each round registers the source moved by the previous rounds' estimate.
    first = register(
        template, source, method="icp", model=small_masknet, iterations=1, max_iterations=3
    )
    np.testing.assert_allclose(result.rounds[0], first.transform, atol=1e-12)


def test_times_keys(pairs, small_masknet):
    start = time.perf_counter()
    result = register(
        pairs.template[0].numpy(), pairs.source[0].numpy(), method="icp", model=small_masknet
    )
    elapsed = time.perf_counter() - start  # the caller's own clock around the call
    assert set(result.times) == {"sample", "mask", "register", "refine", "total"}
    stages = [result.times[k] for k in ("sample", "mask", "register", "refine")]
    assert min(stages) >= 0 and result.times["mask"] > 0 and result.times["register"] > 0
    assert result.times["refine"] == 0  # no refine_iterations asked for
    assert sum(stages) <= result.times["total"] <= elapsed
    plain = register(pairs.template[0].numpy(), pairs.source[0].numpy(), use_mask=False)
    assert plain.times["mask"] == 0 and plain.mask is None


def test_mask_is_top_k_with_k_equal_m(pairs, small_masknet):
    template, source = pairs.template.numpy(), pairs.source.numpy()
    result = register(template, source, method="icp", model=small_masknet)
    assert (result.mask.sum(-1) == source.shape[1]).all()
    np.testing.assert_array_equal(result.mask, small_masknet.predict_mask(template, source))
    k = register(template, source, method="icp", model=small_masknet, k=100)
    assert (k.mask.sum(-1) == 100).all()
    scores = small_masknet.predict(template, source)
    thr = float(np.median(scores))
    by_threshold = register(template, source, method="icp", model=small_masknet, mask_threshold=thr)
    np.testing.assert_array_equal(by_threshold.mask, scores >= thr)


class _FixedMask:
    """Stands in for MaskNet: a fixed mask, and a record of what it was asked."""

    def __init__(self, mask: np.ndarray):
        self.mask = mask
        self.calls: list[tuple[np.ndarray, np.ndarray, int | None, float | None]] = []

    def predict_masks(self, template, source, *, k=None, threshold=None, precision="auto"):
        self.calls.append((template.copy(), source.copy(), k, threshold))
        return self.mask, None


def test_only_masked_template_points_take_part(pairs):
    template, source = pairs.template.numpy(), pairs.source.numpy()
    mask = pairs.mask.numpy()  # the true inliers
    result = register(template, source, method="icp", model=_FixedMask(mask), max_iterations=20)
    np.testing.assert_array_equal(result.mask, mask)
    # Replace the unmasked points by copies of source points, where they lure plain ICP
    # (started at the identity) into staying there; the masked registration never sees them.
    cluttered = template.copy()
    for b in range(len(template)):
        cluttered[b, ~mask[b]] = source[b, : int((~mask[b]).sum())]
    moved = register(cluttered, source, method="icp", model=_FixedMask(mask), max_iterations=20)
    # The clutter moves the call's frame (the template's centroid), whose coordinates hold
    # float32 values: the same registration to that precision.
    np.testing.assert_allclose(moved.transform, result.transform, atol=1e-6)
    plain = register(
        cluttered, source, method="icp", use_mask=False, init="identity", max_iterations=20
    )
    assert np.abs(plain.transform - result.transform).max() > 1e-3


def test_each_round_masks_the_moved_source(pairs):
    template, source = pairs.template.numpy(), pairs.source.numpy()
    fake = _FixedMask(pairs.mask.numpy())
    result = register(
        template,
        source,
        method="icp",
        model=fake,
        iterations=3,
        k=500,
        max_iterations=2,
        refine_masks="network",
    )
    assert len(fake.calls) == 3
    frame = Frame.of(template.astype(np.float64))  # the network sees the call's frame
    for i, (tpl, src, k, threshold) in enumerate(fake.calls):
        np.testing.assert_array_equal(tpl, frame.points_in(template.astype(np.float64)))
        assert k == 500 and threshold is None
        if i == 0:
            np.testing.assert_allclose(src, frame.points_in(source.astype(np.float64)))
        else:
            before = result.rounds[i - 1]
            expected = source @ before[:, :3, :3].transpose(0, 2, 1) + before[:, None, :3, 3]
            # 1e-6: float32 values in the frame, rounded before the move here, after there
            np.testing.assert_allclose(src, frame.points_in(expected), atol=1e-6)


def test_a_weights_path_as_model_says_how_to_load_it(pairs):
    with pytest.raises(MaskNetError, match=r"model must be a mask network, got str .*from_file"):
        register(pairs.template[0].numpy(), pairs.source[0].numpy(), model="best.safetensors")


def test_default_model_is_loaded_once(monkeypatch, pairs, small_masknet):
    from masknet.registration import plan

    calls = []

    def fake_pretrained(*args, **kwargs):
        calls.append(1)
        return small_masknet

    from masknet.models import CrossMaskNet

    plan.default_model.cache_clear()
    plan.default_mask_x_model.cache_clear()
    # Mask-ICP's default is CrossMaskNet (the paper's MaskNet without Open3D): either loads once.
    monkeypatch.setattr(MaskNet, "pretrained", staticmethod(fake_pretrained))
    monkeypatch.setattr(CrossMaskNet, "pretrained", staticmethod(fake_pretrained))
    try:
        register(pairs.template[0].numpy(), pairs.source[0].numpy(), method="icp", max_iterations=1)
        register(pairs.template[1].numpy(), pairs.source[1].numpy(), method="icp", max_iterations=1)
    finally:
        plan.default_model.cache_clear()
        plan.default_mask_x_model.cache_clear()
    assert calls == [1]


@pytest.mark.parametrize(
    ("template", "source", "match"),
    [
        (np.zeros((10, 2)), np.zeros((5, 2)), "3 columns"),
        (np.zeros((10, 3)), np.zeros((2, 5, 3)), "both be"),
        (np.zeros((2, 10, 3)), np.zeros((3, 5, 3)), "batch sizes"),
        (np.zeros((2, 3)), np.zeros((5, 3)), "at least 3"),
        (np.full((10, 3), np.nan), np.zeros((5, 3)), "NaN"),
        (np.array([["a", "b", "c"]] * 4), np.zeros((5, 3)), "numbers"),
    ],
)
def test_bad_clouds_raise(template, source, match):
    with pytest.raises(MaskNetError, match=match):
        register(template, source, use_mask=False)


def test_bad_arguments_raise(pairs, small_masknet):
    template, source = pairs.template[0].numpy(), pairs.source[0].numpy()
    with pytest.raises(MaskNetError, match="method"):
        register(template, source, method="ndt", model=small_masknet)
    with pytest.raises(MaskNetError, match="iterations"):
        register(template, source, iterations=0, model=small_masknet)
    with pytest.raises(MaskNetError, match="unknown option"):
        register(template, source, model=small_masknet, max_iters=3)
    with pytest.raises(MaskNetError, match="either k or mask_threshold"):
        register(template, source, method="icp", model=small_masknet, k=10, mask_threshold=0.5)
    with pytest.raises(MaskNetError, match="k must be"):
        register(template, source, method="icp", model=small_masknet, k=0)
    with pytest.raises(MaskNetError, match="use_mask"):
        register(template, source, method="icp", use_mask=False, k=10)
    with pytest.raises(MaskNetError, match="max_correspondence_distance"):
        register(template, source, use_mask=False, max_correspondence_distance=-1.0)


def test_open3d_icp_method(pairs, full_pairs, small_masknet):
    _open3d_or_skip()
    template, source = full_pairs.template.numpy(), full_pairs.source.numpy()
    theirs = register(template, source, method="open3d-icp", use_mask=False, max_iterations=50)
    ours = register(template, source, method="icp", use_mask=False, max_iterations=50)
    assert theirs.transform.shape == (2, 4, 4)
    np.testing.assert_allclose(theirs.transform, ours.transform, atol=1e-6)
    assert (theirs.info["iterations"] == -1).all()
    # Mask-ICP through Open3D: the same fixed number of steps as ours on the same mask.
    template, source = pairs.template.numpy(), pairs.source.numpy()
    kwargs = {"model": small_masknet, "max_iterations": 4, "max_correspondence_distance": 0.2}
    theirs = register(
        template, source, method="open3d-icp", relative_fitness=0, relative_rmse=0, **kwargs
    )
    ours = register(template, source, method="icp", relative_rmse=0, **kwargs)
    np.testing.assert_array_equal(theirs.mask, ours.mask)
    # register() runs our ICP in float32 (centred); icp() itself matches Open3D to 1e-15
    # in float64 (tests/registration/solvers/test_icp.py).
    np.testing.assert_allclose(theirs.transform, ours.transform, atol=1e-6)
    np.testing.assert_allclose(theirs.info["fitness"], ours.info["fitness"], atol=1e-12)
    single = register(template[0], source[0], method="open3d-icp", **kwargs)
    assert single.transform.shape == (4, 4) and single.mask.shape == (template.shape[1],)


def test_open3d_icp_method_without_open3d(monkeypatch, pairs):
    def broken():
        raise ImportError("No module named 'open3d'")

    monkeypatch.setattr(masknet._open3d, "_load_open3d", broken)
    with pytest.raises(MaskNetError, match="open3d ICP backend needs Open3D"):
        register(
            pairs.template[0].numpy(), pairs.source[0].numpy(), method="open3d-icp", use_mask=False
        )


# --------------------------------------------------------------------- PointNetLK, init, refine


@pytest.fixture(scope="module")
def lk_network():
    from masknet.models import PointNetLK

    torch.manual_seed(0)
    return PointNetLK(encoder_channels=(64, 64, 64, 128, 256)).eval()


def test_pointnetlk_recovers_a_known_transform(full_pairs, lk_network):
    template, source = full_pairs.template.numpy(), full_pairs.source.numpy()
    truth = full_pairs.transform.double().numpy()
    result = register(
        template, source, method="pointnetlk", use_mask=False, network=lk_network, max_iterations=20
    )
    # the pairs are turned by 0.04-0.08 rad; the network recovers them to about 1e-6 rad
    assert _angle(result.R, truth[:, :3, :3]).max() < 1e-3
    np.testing.assert_allclose(result.t, truth[:, :3, 3], atol=1e-4)
    assert set(result.info) == {
        "converged",
        "iterations",
        "feature_residual",
        "fitness",
        "inlier_rmse",
    }


def test_pointnetlk_scale_does_not_matter(full_pairs, lk_network):
    """Clouds in millimetres give the same rotation and 1000x the translation."""
    template, source = full_pairs.template[0].numpy(), full_pairs.source[0].numpy()
    metres = register(template, source, method="pointnetlk", use_mask=False, network=lk_network)
    mm = register(
        template * 1000, source * 1000, method="pointnetlk", use_mask=False, network=lk_network
    )
    np.testing.assert_allclose(mm.R, metres.R, atol=1e-4)
    np.testing.assert_allclose(mm.t, 1000 * metres.t, atol=0.1)


def test_mask_pointnetlk_uses_the_mask(pairs, lk_network):
    template, source = pairs.template.numpy(), pairs.source.numpy()
    mask = pairs.mask.numpy()
    result = register(
        template, source, method="pointnetlk", model=_FixedMask(mask), network=lk_network
    )
    cluttered = template.copy()
    cluttered[~mask] = 7.0  # far away; masked out, so they cannot matter
    moved = register(
        cluttered, source, method="pointnetlk", model=_FixedMask(mask), network=lk_network
    )
    np.testing.assert_allclose(moved.transform, result.transform, atol=1e-4)


def test_centroid_init_beats_identity_on_a_large_translation(full_pairs):
    template = full_pairs.template[0].numpy()
    source = template[::-1] + np.array([3.0, -2.0, 1.0])  # pure translation, far away
    far = register(
        template, source, method="icp", use_mask=False, init="identity", max_iterations=3
    )
    near = register(template, source, method="icp", use_mask=False, max_iterations=3)
    np.testing.assert_allclose(near.t, [-3.0, 2.0, -1.0], atol=1e-6)
    assert np.abs(far.t - [-3.0, 2.0, -1.0]).max() > 0.1


def test_refinement_runs_on_the_whole_template(pairs):
    template, source = pairs.template.numpy(), pairs.source.numpy()
    truth = pairs.transform.double().numpy()
    mask = pairs.mask.numpy().copy()
    mask[:, ::2] = False  # a poor mask leaves ICP off the truth
    coarse = register(template, source, method="icp", model=_FixedMask(mask), max_iterations=5)
    refined = register(
        template,
        source,
        method="icp",
        model=_FixedMask(mask),
        max_iterations=5,
        refine_iterations=30,
    )
    assert refined.times["refine"] > 0 and coarse.times["refine"] == 0
    assert _angle(refined.R, truth[:, :3, :3]).mean() < _angle(coarse.R, truth[:, :3, :3]).mean()


def test_large_single_pair_is_sampled_and_the_mask_covers_every_point(small_masknet):
    rng = np.random.default_rng(0)
    template = rng.normal(size=(5000, 3))
    template /= np.linalg.norm(template, axis=1, keepdims=True)  # a dense sphere
    source = template[template[:, 2] > -0.3] + 0.05
    # Mask-ICP: the default ends such a pair at its consensus front end, before a network.
    result = register(template, source, model=small_masknet, max_points=256, method="icp")
    n, m = result.sampled
    assert n == 256 and 100 < m < 256  # the source at the template's spacing
    assert result.mask.shape == (5000,) and result.mask.any() and not result.mask.all()
    assert result.times["sample"] > 0


def test_large_batches_are_refused(small_masknet):
    template = np.zeros((2, 2000, 3)) + np.random.default_rng(0).normal(size=(2, 2000, 3))
    with pytest.raises(MaskNetError, match="one pair at a time"):
        register(template, template, model=small_masknet)


def test_unknown_init_and_bad_refine_are_refused(pairs, small_masknet):
    template, source = pairs.template.numpy(), pairs.source.numpy()
    with pytest.raises(MaskNetError, match="unknown init"):
        register(template, source, model=small_masknet, init="ransac")
    with pytest.raises(MaskNetError, match="refine_iterations"):
        register(template, source, method="icp", model=small_masknet, refine_iterations=-1)
    with pytest.raises(MaskNetError, match="max_points must be an integer >= 3, got 2"):
        register(template[0], source[0], model=small_masknet, max_points=2)


@pytest.mark.parametrize("method", ["open3d-ransac", "open3d-fgr"])
def test_open3d_global_methods_recover_a_clean_pair(full_pairs, method):
    if not _open3d_available():
        pytest.skip("Open3D unavailable")
    template, source = full_pairs.template[0].numpy(), full_pairs.source[0].numpy()
    truth = full_pairs.transform[0].double().numpy()
    result = register(template, source, method=method, use_mask=False)
    # a clean full pair turned by 0.08 rad: recovered to about 1e-4 rad (FGR), 4e-8 (RANSAC)
    assert _angle(result.R, truth[:3, :3]) < 1e-3
    np.testing.assert_allclose(result.t, truth[:3, 3], atol=1e-3)
    assert result.info["fitness"] > 0.5


def test_open3d_ransac_is_repeatable_and_leaves_the_thread_limit(pairs):
    o3d = _open3d_or_skip()
    before = o3d.utility.get_max_threads()
    template, source = pairs.template[0].numpy(), pairs.source[0].numpy()
    runs = [register(template, source, method="open3d-ransac", use_mask=False) for _ in range(3)]
    assert all(np.array_equal(r.transform, runs[0].transform) for r in runs)
    assert o3d.utility.get_max_threads() == before


def _open3d_available() -> bool:
    try:
        require_open3d("test")
    except MaskNetError:
        return False
    return True


_TINY_NETWORKS = {
    "dcp": {"channels": [8, 16], "embedding": 16, "k": 8, "heads": 2, "feedforward": 32},
    "prnet": {"channels": [8, 16], "embedding": 16, "k": 8, "heads": 2, "feedforward": 32},
    "pcrnet": {"encoder_channels": [16, 32], "head_channels": [32, 16]},
    "rpmnet": {"features": 16, "k": 8, "parameter_channels": [16, 32], "input_points": 300},
}


@pytest.mark.parametrize("method", list(_TINY_NETWORKS))
def test_learned_methods_run_with_and_without_mask(pairs, method):
    from masknet.models import REGISTRATION_NETWORKS

    torch.manual_seed(0)
    network = REGISTRATION_NETWORKS[method](**_TINY_NETWORKS[method]).eval()
    template, source = pairs.template.numpy(), pairs.source.numpy()
    mask = pairs.mask.numpy()
    plain = register(template, source, method=method, use_mask=False, network=network)
    masked = register(template, source, method=method, model=_FixedMask(mask), network=network)
    for result in (plain, masked):
        assert result.transform.shape == (3, 4, 4)
        np.testing.assert_allclose(
            result.R @ result.R.transpose(0, 2, 1), np.eye(3)[None].repeat(3, 0), atol=1e-5
        )
    # Mask-X: the masked-out template points cannot matter. They trade places among
    # themselves, which keeps the template's extent (the scale the network sees).
    cluttered = template.copy()
    for i in range(len(mask)):
        cluttered[i, ~mask[i]] = template[i, ~mask[i]][::-1]
    moved = register(cluttered, source, method=method, model=_FixedMask(mask), network=network)
    np.testing.assert_allclose(moved.transform, masked.transform, atol=1e-4)
    if method in ("prnet", "rpmnet"):
        inliers = masked.correspondence_inliers
        assert inliers.shape == mask.shape and not inliers[~mask].any()
    else:
        assert masked.correspondence_inliers is None


def test_networks_sample_clouds_above_their_input_size(pairs):
    """rpmnet above was built for 300 points: the 1,024-point template is sampled to 300."""
    from masknet.models import RPMNet

    calls = []

    class Recording(RPMNet):
        def forward(self, template, source, max_iterations=5):
            calls.append((template.shape[1], source.shape[1]))
            return super().forward(template, source, max_iterations)

    torch.manual_seed(0)
    network = Recording(**_TINY_NETWORKS["rpmnet"]).eval()
    template, source = pairs.template[0].numpy(), pairs.source[0].numpy()
    register(template, source, method="rpmnet", use_mask=False, network=network)
    assert calls == [(300, round(len(source) * 300 / len(template)))]


def test_threshold_masks_of_different_sizes_run_pair_by_pair(pairs):
    from masknet.models import DCP

    torch.manual_seed(0)
    network = DCP(**_TINY_NETWORKS["dcp"]).eval()
    template, source = pairs.template.numpy(), pairs.source.numpy()
    mask = pairs.mask.numpy().copy()
    mask[0, np.flatnonzero(mask[0])[:50]] = False  # pair 0 keeps 50 fewer points
    batched = register(template, source, method="dcp", model=_FixedMask(mask), network=network)
    for i in range(3):
        single = register(
            template[i], source[i], method="dcp", model=_FixedMask(mask[i : i + 1]), network=network
        )
        np.testing.assert_allclose(batched.transform[i], single.transform, atol=1e-5)


def test_learned_methods_refuse_a_mask_of_fewer_than_three_points(pairs):
    from masknet.models import DCP

    network = DCP(**_TINY_NETWORKS["dcp"]).train()
    mask = np.zeros(pairs.mask.shape, bool)
    mask[:, :2] = True
    template, source = pairs.template.numpy(), pairs.source.numpy()
    with pytest.raises(MaskNetError, match="kept 2 template point"):
        register(template, source, method="dcp", model=_FixedMask(mask), network=network)
    assert network.training  # the caller's mode is restored


def test_result_carries_open3d_names_and_converged_is_none_where_not_reported(one_thread):
    shapes = load_modelnet40(bundled_sample_path(), "test").points[:1]
    pair = make_test_pairs(shapes, 1, PairConfig(), seed=2)
    template, source = pair.template[0].double().numpy(), pair.source[0].double().numpy()
    icp = register(template, source, method="icp", use_mask=False)
    assert icp.transformation is icp.transform
    assert isinstance(icp.converged, bool) and icp.converged == icp.info["converged"]
    # Open3D's figures at the returned pose and 1.5 template spacings, as
    # evaluate_registration measures any result (the pair is turned 44 deg and 10 ICP
    # iterations leave it 15 deg off: about half the points fit)
    for result in (icp, register(template, source, method="dcp", use_mask=False)):
        quality = evaluate_registration(
            template=template, source=source, transform=result.transform
        )
        assert abs(float(result.fitness) - float(quality.fitness)) <= 2 / len(source)
        np.testing.assert_allclose(float(result.inlier_rmse), quality.inlier_rmse, rtol=1e-3)
    assert 0.2 < float(icp.fitness) < 0.8
    dcp = register(template, source, method="dcp", use_mask=False)
    assert dcp.converged is None  # DCP has no stopping rule


def test_a_default_call_crosses_between_numpy_and_torch_twice(monkeypatch, pairs):
    """The default call stays in numpy but for the network: the clouds enter torch in one
    conversion and the mask leaves it in one. Every other stage (frame, ICP, the fit
    check, the mask spread back) is numpy."""
    template, source = pairs.template[0].numpy(), pairs.source[0].numpy()
    assert register(template, source).info["path"] == "fast"  # warm, and the fast path
    crossings: list[str] = []
    for name in ("from_numpy", "as_tensor", "tensor", "asarray"):
        original = getattr(torch, name)

        def counted(*args, _original=original, _name=name, **kwargs):
            if _name == "from_numpy" or (args and isinstance(args[0], np.ndarray)):
                crossings.append(_name)
            return _original(*args, **kwargs)

        monkeypatch.setattr(torch, name, counted)
    for name in ("numpy", "__array__"):
        original = getattr(torch.Tensor, name)

        def counted_out(self, *args, _original=original, _name=name, **kwargs):
            crossings.append(_name)
            return _original(self, *args, **kwargs)

        monkeypatch.setattr(torch.Tensor, name, counted_out)
    result = register(template, source)
    assert result.info["path"] == "fast" and type(result.info["path"]) is str
    assert crossings == ["from_numpy", "numpy"], crossings


def test_each_cloud_is_checked_once(monkeypatch, pairs):
    """register validates at the facade; the network it calls does not check again."""
    import masknet.io_checks as io_checks

    template, source = pairs.template[0].numpy(), pairs.source[0].numpy()
    checked: list[str] = []
    original = io_checks.check_cloud

    def counted(cloud, name, *args, **kwargs):
        checked.append(name)
        return original(cloud, name, *args, **kwargs)

    monkeypatch.setattr(io_checks, "check_cloud", counted)
    register(template, source)
    assert checked == ["template", "source"]
    checked.clear()
    with pytest.raises(MaskNetError, match="source: 1 row contains NaN"):
        bad = source.copy()
        bad[3] = np.nan
        register(template, bad)


def test_fitness_is_open3ds_at_the_cut_off_for_a_masked_loop(pairs):
    """With a mask, a loop and a cut-off, result.fitness is still the pose's fit over every
    source point against the whole template, as evaluate_registration measures it."""
    template, source = pairs.template[0].numpy(), pairs.source[0].numpy()
    result = register(template, source, iterations=2, max_correspondence_distance=0.03)
    quality = evaluate_registration(
        template=template,
        source=source,
        transform=result.transform,
        max_correspondence_distance=0.03,
    )
    assert abs(float(result.fitness) - float(quality.fitness)) <= 2 / len(source)


def test_a_mask_of_under_three_points_is_refused_on_every_path(pairs):
    template, source = pairs.template[0].numpy(), pairs.source[0].numpy()
    paper = MaskNet.pretrained()  # CrossMaskNet, Mask-ICP's default, is surer than 0.999999
    for method in ("icp", "open3d-icp"):
        with pytest.raises(MaskNetError, match="the mask kept [0-2] template point"):
            register(template, source, method=method, mask_threshold=0.999999, model=paper)
    with pytest.raises(MaskNetError, match="the mask kept 2 template point") as refused:
        register(template, source, method="icp", k=2)
    assert "k=2" in str(refused.value) and "threshold" not in str(refused.value)


def test_pose_fit_is_a_type():
    from masknet.registration.judge.fit import PoseFit

    assert isinstance(PoseFit(1.0, 0.0, 1.0), PoseFit)

"""CrossMaskNet: MaskNet's interface, its weights round trip, and what its design promises."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from masknet.errors import MaskNetError
from masknet.models import CrossMaskNet, MaskNet
from masknet.training.masknet_task import MASK_NETWORKS, MaskNetTask

SMALL = {"channels": [8, 8, 16], "features": 16, "head_channels": [16], "keys": 32}


@pytest.fixture
def pair() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    template = rng.normal(size=(200, 3))
    return template, template[:140] @ np.diag([1.0, -1.0, -1.0]) + 0.3


def test_scores_and_masks_follow_masknets_interface(pair):
    model = CrossMaskNet(**SMALL).eval()
    template, source = pair
    scores = model.predict(template, source, precision="fp32")
    assert scores.shape == (200,) and ((scores >= 0) & (scores <= 1)).all()
    mask = model.predict_mask(template, source, precision="fp32")
    assert mask.dtype == bool and mask.sum() == 140  # top-k, k = M
    batch = model.predict(np.stack([template] * 2), np.stack([source] * 2), precision="fp32")
    np.testing.assert_allclose(batch[0], scores, atol=1e-5)
    assert model.predict_masks(template, source, precision="fp32")[1] is None


def test_each_cloud_is_centred_on_its_own_centroid(pair):
    model = CrossMaskNet(**SMALL).eval()
    template, source = (torch.as_tensor(c, dtype=torch.float32)[None] for c in pair)
    with torch.no_grad():
        moved = model(template + 5.0, source - 2.0)
        np.testing.assert_allclose(moved, model(template, source), atol=1e-5)


def test_attention_lets_the_source_change_the_template_scores(pair):
    model = CrossMaskNet(**SMALL).eval()
    template, source = pair
    a = model.predict(template, source, precision="fp32")
    b = model.predict(template, source[::-1][:70] * [1, 2, 1], precision="fp32")
    assert np.abs(a - b).max() > 1e-4


def test_weights_round_trip_with_their_architecture(tmp_path, pair):
    model = CrossMaskNet(**SMALL).eval()
    model.save(tmp_path / "w.safetensors")
    loaded = CrossMaskNet.from_file(tmp_path / "w.safetensors")
    assert loaded.config == model.config
    np.testing.assert_array_equal(
        loaded.predict(*pair, precision="fp32"), model.predict(*pair, precision="fp32")
    )
    with pytest.raises(MaskNetError, match="not MaskNet weights"):
        MaskNet.from_file(tmp_path / "w.safetensors")


def test_bad_sizes_are_refused():
    with pytest.raises(ValueError, match="divisible by heads"):
        CrossMaskNet(features=30, heads=4)


def test_the_training_task_builds_either_network():
    assert set(MASK_NETWORKS) == {"masknet", "crossmasknet"}
    task = MaskNetTask(network="crossmasknet", model_config=SMALL)
    assert isinstance(task.build_model(), CrossMaskNet)
    assert task.describe()["network"] == "crossmasknet"
    assert "network" not in MaskNetTask().describe()  # earlier runs' settings unchanged
    with pytest.raises(ValueError, match="network must be one of"):
        MaskNetTask(network="pointnet")


def test_auto_precision_is_fp32_on_a_cpu_where_bf16_is_slower():
    from masknet.runtime import default_precision

    cpu = torch.device("cpu")
    assert CrossMaskNet(**SMALL).auto_precision(cpu) == "fp32"
    assert MaskNet().auto_precision(cpu) == default_precision(cpu)


def test_the_scorer_keeps_no_autograd_graph(pair):
    # A graph kept with each batch's scores made an evaluation of 1,000 pairs grow past
    # 20 GB; the scorer runs without autograd, as MaskNet's fused path does.
    template, source = pair
    net = CrossMaskNet(**SMALL)
    as_batch = [torch.as_tensor(c, dtype=torch.float32)[None] for c in (template, source)]
    scores = net.scorer("fp32")(*as_batch)
    assert scores.grad_fn is None and not scores.requires_grad


# FPFH descriptor inputs (descriptors="fpfh"; Open3D).
DESCRIBED = SMALL | {"descriptors": "fpfh"}


@pytest.fixture
def surface_pair() -> tuple[np.ndarray, np.ndarray]:
    """A smooth closed surface (an ellipsoid, 300 points) and a part of it, in metres."""
    rng = np.random.default_rng(1)
    unit = rng.normal(size=(300, 3))
    template = unit / np.linalg.norm(unit, axis=1, keepdims=True) * [1.0, 0.6, 0.3]
    return template, template[template[:, 0] > -0.3]


def _turn(degrees: float) -> np.ndarray:
    a = np.radians(degrees)
    about_z = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    about_x = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    return about_z @ about_x


def test_descriptors_do_not_change_with_a_turn_or_the_units(surface_pair):
    from masknet.models.descriptors import pair_descriptors

    template, source = (torch.as_tensor(c, dtype=torch.float32)[None] for c in surface_pair)
    t, s = pair_descriptors(template, source)
    assert t.shape == (1, 300, 34) and s.shape == (1, len(surface_pair[1]), 34)
    assert t[..., :33].std() > 0.01  # not a constant
    turn = torch.as_tensor(_turn(40.0), dtype=torch.float32)
    t_turned, s_turned = pair_descriptors(template, 1000.0 * source @ turn.T + 7.0)
    for turned, still in ((t_turned, t), (s_turned, s)):
        # Equal but for float32 rounding, which may move a rare angle to the next bin.
        off = (turned - still).abs()
        assert (off < 5e-3).float().mean() > 0.999 and off.max() < 0.05


def test_each_match_distance_is_to_the_nearest_descriptor_of_the_other_cloud(surface_pair):
    """One distance matrix, read along both axes, gives both clouds' match channels."""
    from masknet.models.descriptors import pair_descriptors

    template, source = (torch.as_tensor(c, dtype=torch.float32)[None] for c in surface_pair)
    t, s = pair_descriptors(template, source)
    ft, fs = t[0, :, :33].double(), s[0, :, :33].double()
    # float64 reference; the channels come from a float32 matrix (|a|^2 - 2ab + |b|^2).
    near = {"atol": 2e-4, "rtol": 0.0}
    torch.testing.assert_close(t[0, :, 33].double(), torch.cdist(ft, fs).amin(1), **near)
    torch.testing.assert_close(s[0, :, 33].double(), torch.cdist(fs, ft).amin(1), **near)
    assert s[0, :, 33].max() > 0  # a distance, not a placeholder


def test_descriptor_inputs_round_trip_and_predict(tmp_path, surface_pair):
    model = CrossMaskNet(**DESCRIBED).eval()
    assert model.config["descriptors"] == "fpfh" and "descriptors" not in CrossMaskNet().config
    model.save(tmp_path / "w.safetensors")
    loaded = CrossMaskNet.from_file(tmp_path / "w.safetensors")
    assert loaded.config == model.config and loaded.descriptors == "fpfh"
    template, source = surface_pair
    scores = loaded.predict(template, source, precision="fp32")
    assert scores.shape == (300,) and ((scores >= 0) & (scores <= 1)).all()
    np.testing.assert_array_equal(scores, model.predict(template, source, precision="fp32"))
    batch = model.predict(np.stack([template] * 2), np.stack([source] * 2), precision="fp32")
    np.testing.assert_allclose(batch[1], scores, atol=1e-5)
    # The descriptors reach the scores: the same clouds without them score otherwise.
    plain = CrossMaskNet(**SMALL).eval()
    plain.load_state_dict(
        {k: v for k, v in model.state_dict().items() if "edges.0" not in k}, strict=False
    )
    assert np.abs(plain.predict(template, source, precision="fp32") - scores).max() > 1e-4


def test_descriptor_inputs_need_no_open3d(monkeypatch, surface_pair):
    import masknet._open3d

    def broken():
        raise ImportError("No module named 'open3d'")

    monkeypatch.setattr(masknet._open3d, "_load_open3d", broken)
    model = CrossMaskNet(**DESCRIBED).eval()  # the same features, by numpy
    scores = model.predict(*surface_pair, precision="fp32")
    assert scores.shape == (300,) and np.isfinite(scores).all()
    monkeypatch.undo()
    if masknet._open3d.has_open3d():
        with_open3d = model.predict(*surface_pair, precision="fp32")
        np.testing.assert_allclose(scores, with_open3d, atol=1e-5)


def test_an_unknown_descriptor_is_refused():
    with pytest.raises(MaskNetError, match="descriptors must be None or one of"):
        CrossMaskNet(descriptors="shot")


def test_a_training_step_with_descriptor_inputs(surface_pair):
    # `masknet train --model crossmasknet --model-config '{"descriptors": "fpfh"}'`: the
    # task's step computes the descriptors of each batch and trains through them.
    from masknet.data import PairConfig, make_test_pairs

    shapes = np.stack([surface_pair[0] * s for s in (1.0, 0.5, 2.0, 1.5)]).astype(np.float32)
    batch = make_test_pairs(shapes, 2, PairConfig(), seed=0)
    task = MaskNetTask(network="crossmasknet", loss="bce", model_config=DESCRIBED)
    model = task.build_model()
    loss, metrics = task.step(model, batch, torch.device("cpu"))
    loss.backward()
    first = model.encoder.edges[0][0].weight
    assert first.shape == (8, 2 * (3 + 34))  # [x_j - x_i; x_i], each xyz and descriptors
    assert first.grad[:, 3:37].abs().sum() > 0
    assert 0.0 <= metrics["precision"] <= 1.0


def test_fpfh_descriptors_are_open3d_s_features(surface_pair):
    """The networks were trained on Open3D's features: the numpy ones are the same."""
    o3d = pytest.importorskip("open3d")
    from masknet.geometry.clouds import median_spacing
    from masknet.geometry.features import fpfh_features
    from masknet.models.descriptors import (
        FPFH_NEIGHBOURS,
        FPFH_SPACINGS,
        fpfh_descriptors,
        numpy_fpfh_descriptors,
    )

    for cloud in surface_pair:
        voxel = FPFH_SPACINGS * median_spacing(cloud)
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud))
        feature = fpfh_features(o3d, pc, voxel, FPFH_NEIGHBOURS, orient=True)
        expected = (np.asarray(feature.data).T / 200.0).astype(np.float32)
        np.testing.assert_allclose(numpy_fpfh_descriptors(cloud), expected, rtol=0, atol=1e-6)
        np.testing.assert_array_equal(fpfh_descriptors(cloud, o3d), expected)
    np.testing.assert_array_equal(numpy_fpfh_descriptors(np.ones((5, 3))), 0.0)  # one point

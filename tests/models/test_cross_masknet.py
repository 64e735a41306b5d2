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

"""The shipped weights load offline and do far better than chance on the bundled sample."""

import numpy as np
import pytest

from masknet import MaskNet
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40
from masknet.evaluation.evaluate import evaluate_masknet


@pytest.fixture(scope="module")
def sample() -> np.ndarray:
    return load_modelnet40(bundled_sample_path(), "test").points


# Bars a little under what the shipped models measure on ModelNet40 test pairs
# (0.870 and 0.843 top-k precision over 1,000 pairs, docs/RESULTS.md); chance is 0.70.
@pytest.mark.parametrize(("name", "bar"), [("modelnet40", 0.83), ("modelnet40_seen20", 0.80)])
def test_shipped_weights_beat_chance(name, bar, sample):
    model = MaskNet.pretrained(name)
    assert not model.training
    result = evaluate_masknet(model, sample, num_pairs=120, seed=5, progress=False)
    top_k, chance = result.rows["top-k (k=M)"], result.rows["random top-k"]
    assert chance["precision"] == pytest.approx(0.7, abs=0.02)
    assert top_k["precision"] > bar


def test_predict_mask_on_single_pair(sample):
    model = MaskNet.pretrained()
    from masknet.data import make_test_pairs

    pair = make_test_pairs(sample, 1, PairConfig(), seed=11)
    mask = model.predict_mask(pair.template[0].numpy(), pair.source[0].numpy())
    assert mask.dtype == bool and mask.shape == (1024,) and mask.sum() == 717
    assert (mask & pair.mask[0].numpy()).sum() / mask.sum() > 0.75


def test_the_shipped_crossmasknet_loads_without_pickle():
    import json
    import struct

    from safetensors import safe_open

    from masknet.models import CrossMaskNet
    from masknet.models.weights import read_metadata, shipped_weights_path

    path = shipped_weights_path("crossmasknet_modelnet40.safetensors")
    raw = path.read_bytes()
    (header,) = struct.unpack("<Q", raw[:8])  # safetensors: a JSON header, then raw tensors
    assert raw[8:9] == b"{" and json.loads(raw[8 : 8 + header])
    with safe_open(str(path), framework="pt") as fh:
        assert len(list(fh.keys())) > 10
    card = json.loads(path.with_suffix(".json").read_text())
    assert read_metadata(path)["storage"] == card["storage"]["dtype"]
    model = CrossMaskNet.pretrained("modelnet40")
    assert not model.training and model.descriptors == "fpfh"


def test_the_shipped_crossmasknet_beats_the_papers_mask(sample):
    from masknet.models import CrossMaskNet

    cross, paper = CrossMaskNet.pretrained("modelnet40"), MaskNet.pretrained()
    found = {
        name: evaluate_masknet(model, sample, num_pairs=12, seed=5, progress=False)
        for name, model in (("cross", cross), ("paper", paper))
    }
    top_k = {name: r.rows["top-k (k=M)"]["precision"] for name, r in found.items()}
    assert top_k["cross"] > 0.95 and top_k["cross"] > top_k["paper"] + 0.04  # 0.974, 0.888

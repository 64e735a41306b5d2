"""The paper-style reference computes the same function as MaskNet's fast paths."""

import pytest
import torch

from masknet.evaluation.timing import median_ms
from masknet.models import MaskNet
from masknet.models.reference import PaperMaskNet


def test_reference_matches_masknet_and_fused():
    torch.manual_seed(0)
    model = MaskNet(encoder_channels=(16, 32, 64), head_channels=(64, 32))
    model.train()
    with torch.no_grad():
        for _ in range(3):  # non-trivial BatchNorm statistics
            model(torch.randn(4, 100, 3) * 2, torch.randn(4, 70, 3))
    model.eval()
    t, s = torch.randn(3, 200, 3), torch.randn(3, 150, 3) + 5
    with torch.no_grad():
        ref = PaperMaskNet(model)(t, s)
        torch.testing.assert_close(ref, model(t, s), atol=1e-6, rtol=0)
        torch.testing.assert_close(ref, model.fused("fp32")(t, s), atol=1e-6, rtol=0)
    assert ref.shape == (3, 200)


def test_median_ms_measures_time():
    import time

    assert 4 <= median_ms(lambda: time.sleep(0.005), repeats=3, warmup=1) < 50


def test_variant_agreement_and_timing_of_every_variant(small_masknet):
    from masknet.data import bundled_sample_path, load_modelnet40
    from masknet.evaluation.timing import masknet_variants, time_variants, variant_agreement

    model = small_masknet
    points = load_modelnet40(bundled_sample_path(), "test").points[:8]
    variants = masknet_variants(model, extended=True)
    variants.pop("torch.compile (split head, fp32)")  # compiling takes a minute; measured in docs
    agreement = variant_agreement(variants, points, num_pairs=8)
    assert agreement["split head, fp32"]["point_agreement"] == 1.0
    assert agreement["fused, fp32"]["point_agreement"] > 0.999
    assert agreement["split head, fp32"]["precision_change"] == 0.0
    # Lower precision flips few decisions: measured 0.969 (bf16) and 0.941 (int8) for this
    # small random network; the shipped one agrees to 0.997 (docs/RESULTS.md).
    assert 0.95 <= agreement["fused, bf16"]["point_agreement"] < 1.0
    assert 0.90 <= agreement["dynamic int8 (Linear)"]["point_agreement"] < 1.0
    times = time_variants({k: v for k, v in variants.items() if "int8" not in k}, 1, 2)
    reference_ms = times["reference (Conv1d, concat, fp32)"]["ms"]
    for row in times.values():  # each speed-up is the reference's time over the variant's
        assert row["ms"] > 0
        assert row["speedup"] == pytest.approx(reference_ms / row["ms"], rel=1e-9)

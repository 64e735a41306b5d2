"""The paper-style reference computes the same function as MaskNet's fast paths."""

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


def test_mask_agreement_of_fp32_with_itself_is_total():
    from masknet.data import bundled_sample_path, load_modelnet40
    from masknet.evaluation.evaluate import mask_agreement

    torch.manual_seed(0)
    model = MaskNet(encoder_channels=(16, 32), head_channels=(32, 16)).eval()
    points = load_modelnet40(bundled_sample_path(), "test").points[:8]
    same = mask_agreement(model, points, "fp32", num_pairs=8)
    assert same["point_agreement"] == 1.0 and same["precision_change"] == 0.0
    bf16 = mask_agreement(model, points, "bf16", num_pairs=8)
    assert 0.5 < bf16["point_agreement"] <= 1.0

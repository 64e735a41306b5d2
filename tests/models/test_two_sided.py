import numpy as np
import pytest
import torch

from masknet import register
from masknet.data.corruption import CorruptionConfig, corrupt_source
from masknet.data.pairs import PairConfig, make_pairs
from masknet.models.two_sided import TwoSidedMaskNet


def _small() -> TwoSidedMaskNet:
    torch.manual_seed(0)
    return TwoSidedMaskNet(
        encoder_channels=(16, 32),
        head_channels=(32, 16),
        local_channels=(8,),
        source_channels=(16,),
    ).eval()


def test_all_kept_source_gives_the_paper_masknet():
    model = _small()
    gen = torch.Generator().manual_seed(1)
    t, s = torch.rand(2, 40, 3, generator=gen), torch.rand(2, 30, 3, generator=gen)
    with torch.no_grad():
        # Source weights of 1 everywhere: the template branch is the paper's MaskNet.
        for layer in model.source_head:
            layer.weight.zero_()
            layer.bias.fill_(50.0)
        tpl_scores, src_scores = model(t, s)
        assert torch.all(src_scores > 0.99)
        assert torch.allclose(tpl_scores, model.masknet(t, s), atol=1e-5)


def test_predict_masks_takes_its_options_by_keyword():
    model = _small()
    gen = np.random.default_rng(0)
    t, s = gen.random((40, 3)), gen.random((30, 3))
    template_mask, source_mask = model.predict_masks(t, s, k=5)
    assert template_mask.shape == (40,) and template_mask.sum() == 5
    assert source_mask.shape == (30,) and source_mask.dtype == bool
    with pytest.raises(TypeError):
        model.predict_masks(t, s, 5)


def test_frozen_template_branch_gets_no_gradient():
    model = _small().train()
    assert not model.masknet.training  # frozen BatchNorm statistics too
    gen = torch.Generator().manual_seed(2)
    t, s = torch.rand(2, 40, 3, generator=gen), torch.rand(2, 30, 3, generator=gen)
    _, logits = model(t, s, logits=True, template_branch=False)
    logits.sum().backward()
    assert all(p.grad is None for p in model.masknet.parameters())
    assert model.source_point.weight.grad is not None


def test_fine_tuning_a_two_sided_file_keeps_its_weights(tmp_path):
    from masknet.training.two_sided_task import TwoSidedTask

    model = _small()
    path = tmp_path / "two.safetensors"
    model.save(path)
    built = TwoSidedTask(init=str(path)).build_model()
    assert isinstance(built, TwoSidedMaskNet) and built.config["encoder_channels"] == [16, 32]
    for key, value in model.state_dict().items():
        assert torch.equal(built.state_dict()[key], value)


def test_save_load_round_trip(tmp_path):
    model = _small()
    model.save(tmp_path / "m.safetensors")
    loaded = TwoSidedMaskNet.from_file(tmp_path / "m.safetensors")
    rng = np.random.default_rng(0)
    t, s = rng.random((40, 3)), rng.random((30, 3))
    a, b = model.predict(t, s, precision="fp32"), loaded.predict(t, s, precision="fp32")
    assert np.allclose(a[0], b[0]) and np.allclose(a[1], b[1])


def test_corruption_labels_replaced_points():
    gen = torch.Generator().manual_seed(0)
    pairs = make_pairs(torch.rand(4, 64, 3, generator=gen), PairConfig(), gen)
    out = corrupt_source(pairs, CorruptionConfig(max_outlier_ratio=0.3, max_clutter=0.5), gen)
    assert out.source.shape == pairs.source.shape
    changed = (out.source - pairs.source).norm(dim=-1) > 0.05  # beyond 3 sigma of noise
    assert torch.all(~out.source_mask[changed])
    assert (~out.source_mask).any()


def test_shipped_two_sided_masks_remove_outliers():
    model = TwoSidedMaskNet.pretrained()
    gen = torch.Generator().manual_seed(3)
    cloud = torch.nn.functional.normalize(torch.randn(1, 1024, 3, generator=gen), dim=-1)
    pairs = make_pairs(cloud, PairConfig(outlier_ratio=0.2), gen)  # a sphere, 143 outliers
    _, kept = model.predict_masks(pairs.template[0].numpy(), pairs.source[0].numpy())
    truth = pairs.source_mask[0].numpy()
    # Measured (bf16 and fp32 alike): every real point kept, 81 of the 143 outliers (0.566)
    # removed. Floors: 0.45 (a fifth below), and 98% of the real points.
    assert kept[truth].mean() > 0.98
    assert (~kept[~truth]).mean() > 0.45
    result = register(pairs.template[0].numpy(), pairs.source[0].numpy(), model=model)
    assert result.source_mask.shape == (pairs.source.shape[1],)
    # register's source mask is the same network's: the same figures, the same floors
    assert result.source_mask[truth].mean() > 0.98
    assert (~result.source_mask[~truth]).mean() > 0.45

"""Tests for masknet.models.masknet: the three forward paths, predict, masks and weights I/O."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from masknet.errors import MaskNetError
from masknet.geometry import unit_radius
from masknet.models.masknet import FusedMaskNet, MaskNet, ScoredMask, centre, select_mask
from masknet.models.pointnet import PointNetEncoder, fold_batchnorm

SMALL = {"encoder_channels": (16, 32, 32, 64, 128), "head_channels": (128, 64, 32, 16)}


def _clouds(b: int, n: int, m: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    template = torch.randn(b, n, 3, generator=g)
    template = template / template.norm(dim=-1, keepdim=True).amax(1, keepdim=True)
    idx = torch.rand(b, n, generator=g).argsort(1)[:, :m]
    source = torch.gather(template, 1, idx[..., None].expand(-1, -1, 3)) + 0.3
    return template, source


def _trained_stats(model: MaskNet, seed: int = 0) -> MaskNet:
    """Non-trivial BatchNorm: random affine parameters and running stats from real batches.

    The head weights are also scaled up (and the global half down) so that the random
    network's scores vary between points by more than bf16 rounding, as a trained one's do.
    """
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for layer in (model.head_template, model.head_global, *model.head):
            layer.weight.mul_(3.0)
        model.head_global.weight.mul_(0.3)
        for norm in model.encoder.norms:
            norm.weight.copy_(0.5 + torch.rand(norm.weight.shape, generator=g))
            norm.bias.copy_(0.2 * torch.randn(norm.bias.shape, generator=g))
        model.train()
        for i in range(3):
            template, source = _clouds(4, 64, 40, seed=100 + i)
            model(template * (1 + i), source)
        # Centred inputs give the first layer a zero batch mean, so shift every mean a bit.
        for norm in model.encoder.norms:
            norm.running_mean.add_(0.1 * torch.randn(norm.running_mean.shape, generator=g))
    model.eval()
    for norm in model.encoder.norms:
        assert int(norm.num_batches_tracked) == 6  # template and source, 3 forwards
        assert not torch.allclose(norm.running_mean, torch.zeros_like(norm.running_mean))
        assert not torch.allclose(norm.running_var, torch.ones_like(norm.running_var))
    return model


pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def model() -> MaskNet:
    torch.manual_seed(0)
    return _trained_stats(MaskNet(**SMALL))


@pytest.fixture(scope="module")
def default_model() -> MaskNet:
    torch.manual_seed(1)
    return _trained_stats(MaskNet(), seed=1)


@pytest.fixture(scope="module")
def clouds() -> tuple[torch.Tensor, torch.Tensor]:
    return _clouds(3, 96, 60, seed=7)


def _fresh(model: MaskNet) -> MaskNet:
    copy = MaskNet(**model.config)
    copy.load_state_dict(model.state_dict())
    return copy.eval()


def test_centre():
    pts = torch.randn(2, 10, 3) + torch.tensor([5.0, -3.0, 1.0])
    c = centre(pts)
    torch.testing.assert_close(c.mean(1), torch.zeros(2, 3), atol=1e-6, rtol=0)
    torch.testing.assert_close(c, pts - pts.mean(1, keepdim=True))


def test_fold_batchnorm_matches_eval_mode(model):
    x = torch.randn(50, 16)
    linear, norm = model.encoder.linears[1], model.encoder.norms[1]
    w, b = fold_batchnorm(linear, norm)
    with torch.no_grad():
        torch.testing.assert_close(x @ w.T + b, norm(linear(x)), atol=1e-5, rtol=1e-5)


def test_encoder_shape_and_values():
    enc = PointNetEncoder((8, 16)).eval()
    g = torch.Generator().manual_seed(0)
    with torch.no_grad():  # seeded weights and non-trivial BatchNorm
        for linear, norm in zip(enc.linears, enc.norms, strict=True):
            linear.weight.normal_(generator=g)
            norm.weight.uniform_(0.5, 1.5, generator=g)
            norm.bias.normal_(0, 0.2, generator=g)
            norm.running_mean.uniform_(-0.5, 0.5, generator=g)
            norm.running_var.uniform_(0.5, 2.0, generator=g)
    points = torch.randn(2, 5, 3, generator=g)
    with torch.no_grad():
        got = enc(points)
    assert enc.out_channels == 16 and got.shape == (2, 5, 16)
    # Each point on its own, by hand: relu((x W^T - mean) / sqrt(var + eps) * gamma + beta).
    x = points.double()
    for linear, norm in zip(enc.linears, enc.norms, strict=True):
        x = x @ linear.weight.double().T
        x = (x - norm.running_mean.double()) / (norm.running_var.double() + norm.eps).sqrt()
        x = torch.relu(x * norm.weight.double() + norm.bias.double())
    torch.testing.assert_close(got, x.float(), atol=1e-6, rtol=1e-5)


def test_output_shape_and_range(model, clouds):
    template, source = clouds
    with torch.no_grad():
        scores = model(template, source)
    assert scores.shape == (3, 96)
    assert ((scores >= 0) & (scores <= 1)).all()
    assert scores.std() > 1e-3  # not a constant function of the input


@pytest.mark.parametrize("name", ["model", "default_model"])
def test_forward_equals_reference(name, request, clouds):
    net = request.getfixturevalue(name)
    template, source = clouds
    with torch.no_grad():
        torch.testing.assert_close(
            net(template, source), net.forward_reference(template, source), atol=1e-5, rtol=0
        )


@pytest.mark.parametrize("name", ["model", "default_model"])
def test_fused_fp32_equals_forward(name, request, clouds):
    net = request.getfixturevalue(name)
    template, source = clouds
    with torch.no_grad():
        expected = net(template, source)
    fused = net.fused("fp32")
    assert isinstance(fused, FusedMaskNet)
    got = fused(template, source)
    assert got.dtype == torch.float32 and got.shape == expected.shape
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=0)


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_fused_chunked_equals_unchunked(model, clouds, precision):
    template, source = clouds
    fused = model.fused(precision)
    full = fused(template, source, chunk_size=None)
    for chunk in (7, 32, 96, 1000):
        torch.testing.assert_close(
            fused(template, source, chunk_size=chunk), full, atol=1e-6, rtol=0
        )


@pytest.mark.parametrize("name", ["model", "default_model"])
def test_fused_bf16_topk_agrees_with_fp32(name, request, clouds):
    net = request.getfixturevalue(name)
    template, source = clouds
    fp32 = net.fused("fp32")(template, source)
    bf16 = net.fused("bf16")(template, source)
    assert bf16.dtype == torch.float32
    err = (bf16 - fp32).abs().max()
    assert err < 0.02
    k = source.shape[1]
    a, b = select_mask(fp32, k=k), select_mask(bf16, k=k)
    assert (a == b).float().mean() >= 0.95
    # Disagreements only where fp32 scores lie within bf16 error of the top-k boundary.
    top = fp32.sort(dim=1, descending=True).values
    boundary = (top[:, k - 1] + top[:, k]) / 2
    near = (fp32 - boundary[:, None]).abs() <= 2 * err
    assert not (a != b)[~near].any()


def test_invariant_to_source_permutation(model, clouds):
    template, source = clouds
    perm = torch.randperm(source.shape[1], generator=torch.Generator().manual_seed(3))
    with torch.no_grad():
        a = model(template, source)
        b = model(template, source[:, perm])
    torch.testing.assert_close(a, b, atol=1e-5, rtol=0)


def test_equivariant_to_template_permutation(model, clouds):
    template, source = clouds
    perm = torch.randperm(template.shape[1], generator=torch.Generator().manual_seed(4))
    with torch.no_grad():
        a = model(template, source)
        b = model(template[:, perm], source)
    torch.testing.assert_close(a[:, perm], b, atol=1e-5, rtol=0)


@pytest.mark.parametrize("shift", [(3.0, -2.0, 5.0), (-0.4, 0.1, 0.0)])
def test_invariant_to_translating_either_cloud(model, clouds, shift):
    template, source = clouds
    v = torch.tensor(shift)
    with torch.no_grad():
        base = model(template, source)
        torch.testing.assert_close(model(template, source + v), base, atol=1e-4, rtol=0)
        torch.testing.assert_close(model(template + v, source), base, atol=1e-4, rtol=0)
    fused = model.fused()
    torch.testing.assert_close(fused(template, source + v), base, atol=1e-4, rtol=0)


def test_source_content_matters(model, clouds):
    template, source = clouds
    with torch.no_grad():
        a = model(template, source)
        b = model(template, source * 2.0)
    assert (a - b).abs().max() > 1e-4


def test_predict_single_and_batched(model, clouds):
    template, source = clouds
    t, s = template.numpy(), source.numpy()
    single = model.predict(t[0], s[0], precision="fp32")
    assert single.shape == (96,) and single.dtype == np.float32
    batched = model.predict(t, s, precision="fp32")
    assert batched.shape == (3, 96) and batched.dtype == np.float32
    np.testing.assert_allclose(batched[0], single, atol=1e-6)
    with torch.no_grad():
        raw = model.predict(t, s, normalize=False, precision="fp32")
        np.testing.assert_allclose(raw, model(template, source).numpy(), atol=1e-5)
        # normalize=True scales each pair by its template's bounding-box radius.
        r = unit_radius(template)[:, None, None]
        np.testing.assert_allclose(batched, model(template / r, source / r).numpy(), atol=1e-5)
    # float64 and list-like inputs are accepted.
    np.testing.assert_allclose(
        model.predict(t[0].astype(np.float64), s[0].tolist(), precision="fp32"), single, atol=1e-6
    )
    np.testing.assert_allclose(
        model.predict(t, s, chunk_size=10, precision="fp32"), batched, atol=1e-6
    )
    np.testing.assert_allclose(
        model.predict(t, s, chunk_size=None, precision="fp32"), batched, atol=1e-6
    )
    # Splitting the batch into calls changes the speed, not the scores.
    for pairs_per_call in (1, 2, 100):
        np.testing.assert_allclose(
            model.predict(t, s, precision="fp32", pairs_per_call=pairs_per_call), batched, atol=1e-6
        )


def test_predict_normalize_makes_units_irrelevant(model, clouds):
    template, source = clouds
    t, s = template.numpy(), source.numpy()
    base = model.predict(t, s)
    for scale in (1000.0, 0.01):
        np.testing.assert_allclose(model.predict(t * scale, s * scale), base, atol=1e-5)
        np.testing.assert_array_equal(
            model.predict_mask(t * scale, s * scale), model.predict_mask(t, s)
        )
    # Without normalisation, units matter.
    assert np.abs(model.predict(t * 1000, s * 1000, normalize=False) - base).max() > 1e-3
    # A unit-radius template (about its bounding-box centre) is left as it is.
    unit = (template / unit_radius(template)[:, None, None]).numpy()
    np.testing.assert_allclose(
        model.predict(unit, s), model.predict(unit, s, normalize=False), atol=1e-6
    )


def test_predict_mask_default_top_k_is_m(model, clouds):
    template, source = clouds
    t, s = template.numpy(), source.numpy()
    mask = model.predict_mask(t[0], s[0])
    assert mask.shape == (96,) and mask.dtype == bool
    assert mask.sum() == 60
    scores = model.predict(t[0], s[0])
    assert scores[mask].min() >= scores[~mask].max()
    batched = model.predict_mask(t, s[:, :50])
    assert batched.shape == (3, 96)
    np.testing.assert_array_equal(batched.sum(1), [50, 50, 50])
    np.testing.assert_array_equal(model.predict_mask(t, s, k=10).sum(1), [10, 10, 10])


def test_predict_mask_threshold(model, clouds):
    template, source = clouds
    t, s = template.numpy(), source.numpy()
    scores = model.predict(t, s)
    threshold = float(np.median(scores))
    mask = model.predict_mask(t, s, threshold=threshold)
    np.testing.assert_array_equal(mask, scores >= threshold)
    assert 0 < mask.sum() < mask.size
    scored = model.predict_mask_with_scores(t, s, threshold=threshold)
    assert isinstance(scored, ScoredMask)
    np.testing.assert_array_equal(scored.mask, mask)
    np.testing.assert_array_equal(scored.scores, scores)


def test_return_scores_is_deprecated(model, clouds):
    template, source = clouds
    t, s = template[0].numpy(), source[0].numpy()
    scored = model.predict_mask_with_scores(t, s)
    with pytest.warns(DeprecationWarning, match="predict_mask_with_scores"):
        mask, scores = model.predict_mask(t, s, return_scores=True)
    np.testing.assert_array_equal(mask, scored.mask)
    np.testing.assert_array_equal(scores, scored.scores)
    with pytest.warns(DeprecationWarning):
        np.testing.assert_array_equal(model.predict_mask(t, s, return_scores=False), mask)


def test_predict_masks_is_the_two_mask_protocol(model, clouds):
    template, source = clouds
    t, s = template.numpy(), source.numpy()
    for args in ({}, {"k": 10}, {"threshold": 0.5}):
        template_mask, source_mask = model.predict_masks(t[0], s[0], **args)
        assert source_mask is None  # MaskNet keeps every source point
        np.testing.assert_array_equal(template_mask, model.predict_mask(t[0], s[0], **args))
    batched, _ = model.predict_masks(t, s[:, :50], precision="fp32")
    assert batched.shape == (3, 96)
    np.testing.assert_array_equal(batched.sum(1), [50, 50, 50])
    with pytest.raises(TypeError):
        model.predict_masks(t, s, 10)  # everything after the clouds is keyword-only


def test_select_mask_rules():
    scores = torch.tensor([[0.1, 0.9, 0.5, 0.7], [0.8, 0.2, 0.6, 0.4]])
    assert select_mask(scores, k=2).tolist() == [
        [False, True, False, True],
        [True, False, True, False],
    ]
    per_row = select_mask(scores, k=torch.tensor([1, 3]))
    assert per_row.tolist() == [[False, True, False, False], [True, False, True, True]]
    assert select_mask(scores, k=10).all()
    assert not select_mask(scores, k=0).any()
    assert select_mask(scores, threshold=0.6).tolist() == [
        [False, True, False, True],
        [True, False, True, False],
    ]
    with pytest.raises(ValueError, match="not both"):
        select_mask(scores, k=2, threshold=0.5)
    with pytest.raises(ValueError):
        select_mask(scores)


TEN = np.random.default_rng(0).random((10, 3))  # a usable cloud of 10 points


@pytest.mark.parametrize(
    ("template", "source", "match"),
    [
        (np.zeros(10), np.zeros(10), "both"),
        (np.zeros((10, 3)), np.zeros((2, 10, 3)), "both"),
        (np.zeros((1, 1, 10, 3)), np.zeros((1, 1, 10, 3)), "both"),
        (np.zeros((10, 2)), np.zeros((10, 3)), "3 columns"),
        (TEN, np.zeros((10, 2)), "3 columns"),
        (np.full((10, 3), np.nan), TEN, "NaN"),
        (TEN, np.array([[0, 0, 0], [np.inf, 0, 0], [1, 1, 1]]), "1 row contains NaN or inf"),
        (TEN, np.zeros((2, 3)), "at least 3"),
        (TEN, TEN.T, "looks transposed"),
        (TEN, np.zeros((10, 3)), "all 10 points are identical"),
        (TEN, np.outer(np.arange(10.0), [1, 2, 3]), "lie on one line"),
        (TEN, TEN * 1e37, "squared distances would overflow"),
        (np.zeros((2, 3)), np.zeros((10, 3)), "at least 3"),
        (np.zeros((2, 10, 3)), np.zeros((3, 10, 3)), "batch"),
    ],
)
def test_predict_bad_inputs_raise(model, template, source, match):
    with pytest.raises(MaskNetError, match=match):
        model.predict(template, source)
    with pytest.raises(MaskNetError):
        model.predict_mask(template, source)


def test_save_and_from_file_round_trip(model, clouds, tmp_path):
    template, source = clouds
    path = tmp_path / "weights.safetensors"
    model.save(path, metadata={"epochs": 3, "note": "test"})
    assert [p.name for p in tmp_path.iterdir()] == ["weights.safetensors"]  # no temporary left
    loaded = MaskNet.from_file(path)
    assert not loaded.training
    assert loaded.config == model.config
    for key, value in model.state_dict().items():
        assert torch.equal(loaded.state_dict()[key], value), key
    t, s = template.numpy(), source.numpy()
    np.testing.assert_array_equal(loaded.predict(t, s), model.predict(t, s))
    with torch.no_grad():
        assert torch.equal(loaded(template, source), model(template, source))
    from safetensors import safe_open

    with safe_open(str(path), framework="pt") as f:
        meta = f.metadata()
    assert meta["note"] == "test" and meta["epochs"] == "3"


def test_from_file_missing_raises(tmp_path):
    with pytest.raises(MaskNetError, match="missing.safetensors"):
        MaskNet.from_file(tmp_path / "missing.safetensors")


def test_from_file_garbage_raises(tmp_path):
    path = tmp_path / "garbage.safetensors"
    path.write_bytes(b"this is not a safetensors file at all" * 10)
    with pytest.raises(MaskNetError, match="garbage.safetensors"):
        MaskNet.from_file(path)


def test_from_file_wrong_architecture_raises(model, tmp_path):
    path = tmp_path / "w.safetensors"
    model.save(path)
    # Rewrite the file with a tensor removed.
    from safetensors.torch import load_file, save_file

    state = load_file(str(path))
    state.pop("head_global.weight")
    save_file(
        state,
        str(path),
        {
            "masknet_config": '{"encoder_channels": [16, 32, 32, 64, 128], '
            '"head_channels": [128, 64, 32, 16]}'
        },
    )
    with pytest.raises(MaskNetError, match="architecture"):
        MaskNet.from_file(path)


def test_fused_cache_invalidated_by_in_place_weight_change(model, clouds):
    net = _fresh(model)
    t, s = (c.numpy() for c in clouds)
    before = net.predict(t, s, normalize=False, precision="fp32")
    with torch.no_grad():
        net.head[-1].bias += 1
    after = net.predict(t, s, normalize=False, precision="fp32")
    assert (after > before + 1e-4).all()  # sigmoid of a larger logit
    with torch.no_grad():
        expected = net(*clouds)
    np.testing.assert_allclose(after, expected.numpy(), atol=1e-5)


def test_fused_cache_invalidated_by_load_state_dict(model, clouds):
    net = _fresh(model)
    t, s = (c.numpy() for c in clouds)
    before = net.predict(t, s, normalize=False, precision="fp32")
    state = {k: v.clone() for k, v in net.state_dict().items()}
    state["encoder.norms.0.running_mean"] += 0.5
    net.load_state_dict(state)
    after = net.predict(t, s, normalize=False, precision="fp32")
    assert np.abs(after - before).max() > 1e-4
    with torch.no_grad():
        np.testing.assert_allclose(after, net(*clouds).numpy(), atol=1e-5)


def test_fused_precision_switch(model, clouds):
    net = _fresh(model)
    template, source = clouds
    fp32 = net.fused("fp32")
    first = fp32(template, source)
    assert fp32.precision == "fp32" and fp32.head_global.dtype == torch.float32
    bf16 = net.fused("bf16")
    assert bf16.precision == "bf16" and bf16.head_global.dtype == torch.bfloat16
    # The bf16 path holds the fp32 path's weights rounded to bf16, and its scores differ
    # by bf16 rounding only (measured 0.0035 at most; 0.02 as in the top-k agreement test).
    assert torch.equal(bf16.head_global, fp32.head_global.to(torch.bfloat16))
    for (w16, b16), (w32, b32) in zip(bf16.encoder, fp32.encoder, strict=True):
        assert torch.equal(w16, w32.to(torch.bfloat16)) and torch.equal(b16, b32.to(torch.bfloat16))
    err = (bf16(template, source) - first).abs().max()
    assert 0 < err < 0.02
    # Switching back gives the fp32 scores again, bit for bit.
    assert torch.equal(net.fused("fp32")(template, source), first)


def test_fused_cache_is_reused_when_weights_unchanged(model):
    net = _fresh(model)
    assert net.fused("fp32") is net.fused("fp32")


def test_select_mask_accepts_one_cloud():
    scores = torch.tensor([0.1, 0.9, 0.5, 0.7])
    assert select_mask(scores, k=2).tolist() == [False, True, False, True]
    assert select_mask(scores, threshold=0.6).shape == (4,)


def test_auto_precision_is_the_hardware_default(model, clouds):
    from masknet.runtime import default_precision

    t, s = (c.numpy() for c in clouds)
    expected = model.predict(t, s, precision=default_precision("cpu"))
    np.testing.assert_array_equal(model.predict(t, s), expected)


def test_source_centring_keeps_the_relative_position(model, clouds, tmp_path):
    """centring="source" (aligned clouds, denoising): a common shift of both clouds changes
    nothing, a shift of the scored cloud alone does; "each" ignores both. All three forward
    paths agree, and the setting travels in the weights file."""
    template, source = clouds
    shared = _fresh(model)
    shared.centring = "source"
    shift = torch.tensor([0.3, -0.2, 0.1])
    with torch.no_grad():
        base = shared(template, source)
        torch.testing.assert_close(
            shared(template + shift, source + shift), base, atol=1e-5, rtol=0
        )
        assert (shared(template + shift, source) - base).abs().max() > 1e-3
        torch.testing.assert_close(model(template + shift, source), model(template, source))
        torch.testing.assert_close(
            shared.forward_reference(template, source), base, atol=1e-5, rtol=0
        )
    torch.testing.assert_close(shared.fused("fp32")(template, source), base, atol=1e-5, rtol=0)
    own = MaskNet(**SMALL, centring="source")
    own.save(tmp_path / "w.safetensors")
    assert MaskNet.from_file(tmp_path / "w.safetensors").centring == "source"
    assert "centring" not in MaskNet(**SMALL).config  # earlier files' configs unchanged
    with pytest.raises(ValueError, match="centring"):
        MaskNet(**SMALL, centring="bbox")

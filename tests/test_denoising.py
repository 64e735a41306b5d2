"""masknet.denoise and the Open3D outlier-removal peers."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from masknet import MaskNetError
from masknet.cli import main
from masknet.denoising import (
    denoise,
    open3d_radius_outlier_removal,
    open3d_statistical_outlier_removal,
)
from masknet.errors import MaskNetWarning


@pytest.fixture(scope="module")
def clouds():
    rng = np.random.default_rng(0)
    sphere = rng.normal(size=(600, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    noisy = np.concatenate([sphere[:400], rng.uniform(-1, 1, size=(40, 3)) * 3])
    return sphere, noisy


def test_denoise_keeps_points_scoring_above_threshold(small_masknet, clouds):
    template, noisy = clouds
    result = denoise(
        template, noisy, method="masknet", model=small_masknet, threshold=0.5, precision="fp32"
    )
    assert result.mask.shape == (440,) and result.scores.shape == (440,)
    np.testing.assert_array_equal(result.mask, result.scores >= 0.5)
    np.testing.assert_array_equal(result.points, noisy[result.mask])
    everything = denoise(template, noisy, method="masknet", model=small_masknet, threshold=0.0)
    assert everything.mask.all()


def test_denoise_scale_comes_from_the_template(small_masknet, clouds):
    """Outliers far away must not change the scores of the other points' scaling."""
    template, noisy = clouds
    a = denoise(template, noisy, method="masknet", model=small_masknet, precision="fp32").scores
    b = denoise(
        template * 1000, noisy * 1000, method="masknet", model=small_masknet, precision="fp32"
    ).scores
    np.testing.assert_allclose(a, b, atol=1e-5)


def test_denoise_refuses_batches_and_bad_thresholds(small_masknet, clouds):
    template, noisy = clouds
    with pytest.raises(MaskNetError, match="one noisy cloud"):
        denoise(template[None], noisy[None], model=small_masknet)
    with pytest.raises(MaskNetError, match="threshold"):
        denoise(template, noisy, method="masknet", model=small_masknet, threshold=2.0)


def test_denoise_takes_the_template_first_and_options_by_keyword(clouds):
    template, noisy = clouds
    with pytest.raises(TypeError):
        denoise(template, noisy, "distance")
    # Far from the noisy cloud's outliers, the template's points are all explained by it.
    assert denoise(noisy, template, method="distance").mask.all()
    assert not denoise(template, noisy, method="distance").mask.all()


def test_denoise_names_each_cloud_in_its_messages(small_masknet, clouds):
    template, noisy = clouds
    holed = noisy.copy()
    holed[5, 0] = np.nan
    with pytest.raises(MaskNetError, match=r"^noisy: 1 row contains NaN"):
        denoise(template, holed)
    with pytest.raises(MaskNetError, match=r"^template: 1 row contains NaN"):
        denoise(holed, noisy)
    with pytest.raises(MaskNetError, match=r"^noisy: shape \(3, 440\) looks transposed"):
        denoise(template, noisy.T)
    with pytest.raises(MaskNetError, match=r"^noisy must have 3 columns"):
        denoise(template, noisy[:, :2])
    # A warning about the noisy cloud names it once, not again under the networks' names.
    for method in ("distance", "masknet"):
        with pytest.warns(MaskNetWarning) as caught:
            denoise(template, noisy[:8], method=method, model=small_masknet, threshold=0.0)
        messages = [str(w.message) for w in caught if w.category is MaskNetWarning]
        assert messages == ["noisy: only 8 points; the result is unreliable"], messages


def test_open3d_filters_remove_an_isolated_cluster(clouds, o3d):
    template, _ = clouds
    far = np.array([[9.0, 9.0, 9.0], [-9.0, 9.0, 0.0], [0.0, -9.0, 9.0]])
    cloud = np.concatenate([template, far])
    for kept in (
        open3d_statistical_outlier_removal(cloud),
        open3d_radius_outlier_removal(cloud, nb_points=4, radius=0.3),
    ):
        assert kept.shape == (603,)
        assert not kept[-3:].any() and kept[:600].mean() > 0.9


def test_cli_denoise_writes_points_and_mask(tmp_path, small_masknet, clouds, capsys):
    template, noisy = clouds
    weights = tmp_path / "w.safetensors"
    small_masknet.save(weights)
    np.savetxt(tmp_path / "noisy.xyz", noisy)
    np.save(tmp_path / "template.npy", template)
    out = tmp_path / "clean.xyz"
    args = ["denoise", str(tmp_path / "template.npy"), str(tmp_path / "noisy.xyz")]
    options = ["--weights", str(weights), "--threshold", "0.5", "--method", "masknet"]
    assert main([*args, "-o", str(out), *options]) == 0
    mask = np.loadtxt(tmp_path / "clean_mask.txt").astype(bool)
    assert mask.shape == (440,)
    np.testing.assert_allclose(np.loadtxt(out).reshape(-1, 3), noisy[mask], atol=1e-6)
    assert "kept" in capsys.readouterr().out


def test_distance_method_removes_far_points(clouds):
    template, noisy = clouds
    result = denoise(template, noisy, method="distance", max_distance=0.05)
    d = np.sqrt(((noisy[:, None] - template[None]) ** 2).sum(-1)).min(1)
    np.testing.assert_array_equal(result.mask, d <= 0.05)
    assert result.mask[:400].all()  # the real points lie on the template
    default = denoise(template, noisy, method="distance")
    assert default.mask[:400].all() and not default.mask.all()
    with pytest.raises(MaskNetError, match="unknown denoising method"):
        denoise(template, noisy, method="median")


def _rotated(points: np.ndarray, degrees: float) -> np.ndarray:
    a = np.radians(degrees)
    rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    return points @ rot.T


def test_shipped_two_sided_denoiser_needs_no_alignment(clouds):
    template, noisy = clouds
    result = denoise(template, _rotated(noisy, 30), method="masknet", precision="fp32")
    real = np.arange(len(noisy)) < 400
    assert (~result.mask[~real]).mean() >= 0.8  # outliers removed
    assert result.mask[real].mean() >= 0.9  # real points kept


def test_two_sided_denoiser_labels_every_point_of_a_large_cloud(clouds):
    template, noisy = clouds
    rng = np.random.default_rng(1)
    large = np.concatenate([noisy + rng.normal(0, 0.005, noisy.shape) for _ in range(6)])
    result = denoise(template, large, method="masknet")
    assert result.mask.shape == result.scores.shape == (len(large),)
    # Copies of one point sit within 0.02 of each other and take their sample's label.
    real = np.tile(np.arange(len(noisy)) < 400, 6)
    assert result.mask[real].mean() >= 0.9 and (~result.mask[~real]).mean() >= 0.8


def test_cli_denoise_masknet_uses_the_shipped_two_sided_weights(tmp_path, clouds, capsys):
    template, noisy = clouds
    np.save(tmp_path / "noisy.npy", _rotated(noisy, 20))
    np.save(tmp_path / "template.npy", template)
    args = ["denoise", str(tmp_path / "template.npy"), str(tmp_path / "noisy.npy")]
    assert main([*args, "-o", str(tmp_path / "clean.npy"), "--method", "masknet"]) == 0
    mask = np.loadtxt(tmp_path / "clean_mask.txt").astype(bool)
    assert mask[:400].mean() >= 0.9 and (~mask[400:]).mean() >= 0.8
    assert "MaskNet score >= 0.5" in capsys.readouterr().out


def test_refined_denoising_of_aligned_clouds_keeps_the_real_points():
    """The shipped refinement mask on aligned clouds with 10% outliers (bundled sample, 20
    pairs): it measured 0.647 of the outliers removed and 0.99993 of the real points kept."""
    from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
    from masknet.denoising import denoise

    shapes = load_modelnet40(bundled_sample_path(), "test").points
    config = PairConfig(max_angle_deg=0, max_translation=0, outlier_ratio=0.1)
    pairs = make_test_pairs(shapes, 20, config, seed=4)
    removed, kept = [], []
    for i in range(20):
        result = denoise(
            pairs.template[i].double().numpy(), pairs.source[i].double().numpy(), method="refined"
        )
        real = pairs.source_mask[i].numpy()
        removed.append((~result.mask & ~real).sum() / (~real).sum())
        kept.append((result.mask & real).sum() / real.sum())
    assert np.mean(removed) >= 0.60 and np.mean(kept) >= 0.995


def test_methods_that_need_aligned_clouds_warn_when_they_are_not(clouds):
    template, noisy = clouds
    turned = noisy @ np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]).T + 1.5  # 90 degrees away
    with pytest.warns(MaskNetWarning, match=r"needs the clouds aligned"):
        kept = denoise(template, turned, method="distance").mask
    assert kept.mean() < 0.5
    with warnings.catch_warnings():
        warnings.simplefilter("error", MaskNetWarning)  # aligned: no warning
        denoise(template, noisy, method="distance")

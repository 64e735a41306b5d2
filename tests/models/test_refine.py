"""The refinement mask network: one frame, both masks, any unit, safetensors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.errors import MaskNetError
from masknet.models.refine import RefineMaskNet, cross_offsets, kth_spacing

SMALL = {"k": 6, "local_channels": (8, 16), "point_channels": (16, 32), "head_channels": (16,)}


@pytest.fixture(scope="module")
def net() -> RefineMaskNet:
    torch.manual_seed(0)
    return RefineMaskNet(**SMALL).eval()


@pytest.fixture(scope="module")
def pair() -> tuple[np.ndarray, np.ndarray]:
    shape = load_modelnet40(bundled_sample_path(), "test").points[0, :300].astype(np.float64)
    return shape, shape[shape[:, 0] > 0]


def test_cross_offsets_measure_the_nearest_point_of_the_other_cloud():
    query = torch.tensor([[[0.0, 0.0, 0.0]]])
    reference = torch.tensor([[[0.0, 0.0, 2.0], [3.0, 0.0, 0.0]]])
    out = cross_offsets(query, reference, 2, torch.tensor([0.5]), torch.tensor([0.25]))
    assert out.shape == (1, 1, 2, 6)
    nearest = out[0, 0, 0]
    assert torch.allclose(nearest[:3], torch.tensor([0.0, 0.0, 4.0]))  # offset / 0.5
    assert torch.isclose(nearest[3], torch.tensor(4.0)) and torch.isclose(
        nearest[4], torch.tensor(2.0)
    )
    assert torch.isclose(nearest[5], torch.log(torch.tensor(2.0)))


def test_kth_spacing_is_the_median_kth_neighbour_distance():
    line = torch.arange(10, dtype=torch.float32)[:, None] * torch.tensor([[0.5, 0.0, 0.0]])
    spacing, idx = kth_spacing(line[None], 3)
    assert float(spacing) == pytest.approx(1.0)  # third neighbour of an inner point
    assert idx.shape == (1, 10, 3) and not (idx[0] == torch.arange(10)[:, None]).any()


def test_scores_do_not_depend_on_unit_position_or_order(net, pair):
    template, source = pair
    t_scores, s_scores = net.predict(template, source)
    assert t_scores.shape == (len(template),) and s_scores.shape == (len(source),)
    shifted = net.predict(1000 * template + 5.0, 1000 * source + 5.0)
    np.testing.assert_allclose(shifted[0], t_scores, atol=2e-4)
    order = np.random.default_rng(0).permutation(len(source))
    np.testing.assert_allclose(net.predict(template, source[order])[1], s_scores[order], atol=2e-4)


def test_relative_position_changes_the_scores(net, pair):
    template, source = pair
    near = net.predict(template, source)[0]
    far = net.predict(template, source + np.array([0.5, 0.0, 0.0]))[0]
    assert np.abs(near - far).max() > 1e-3  # one frame: where the source lies is an input


def test_masks_default_to_as_many_template_points_as_kept_source_points(net, pair):
    template, source = pair
    t_mask, s_mask = net.predict_masks(template, source)
    assert t_mask.dtype == bool and t_mask.sum() == min(len(template), max(3, s_mask.sum()))
    batch = net.predict_masks(template[None].repeat(2, 0), source[None].repeat(2, 0))
    np.testing.assert_array_equal(batch[0][1], t_mask)


def test_with_context_starts_where_the_narrower_network_is_and_then_can_learn(net, pair, tmp_path):
    wider = net.with_context(8)
    assert wider.config["context"] == 8 and "context" not in net.config
    for a, b in zip(wider.predict(*pair), net.predict(*pair), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-6)  # the new channels start at zero weight
    head = wider.template_head[0]
    with torch.no_grad():
        head.weight[:, -8:] = 1.0  # once the head uses them, the neighbourhood counts
    assert np.abs(wider.predict(*pair)[0] - net.predict(*pair)[0]).max() > 1e-3
    path = tmp_path / "wider.safetensors"
    wider.save(path)  # the file rebuilds its own architecture, context included
    again = RefineMaskNet.from_file(path)
    np.testing.assert_allclose(again.predict(*pair)[0], wider.predict(*pair)[0], atol=1e-6)


def test_weights_round_trip(net, tmp_path, pair):
    path = tmp_path / "refine.safetensors"
    net.save(path)
    again = RefineMaskNet.from_file(path)
    np.testing.assert_allclose(again.predict(*pair)[0], net.predict(*pair)[0], atol=1e-6)
    with pytest.raises(MaskNetError, match="no shipped RefineMaskNet weights named"):
        RefineMaskNet.pretrained("nope")


@pytest.fixture(scope="module")
def shipped_pairs():
    from masknet.data import PairConfig, make_test_pairs

    shapes = load_modelnet40(bundled_sample_path(), "test").points
    return {
        "clean": make_test_pairs(shapes, 40, PairConfig(), seed=5),
        "outliers": make_test_pairs(shapes, 40, PairConfig(outlier_ratio=0.1), seed=5),
    }


def _masks_at(refiner, pairs, angle: float) -> tuple[float, float]:
    """Template precision and share of outliers removed, at a residual of ``angle``."""
    from masknet.experiments.rounds import residual_moved

    moved = residual_moved(pairs, angle, 5)
    t_mask, s_mask = refiner.predict_masks(pairs.template.double().numpy(), moved)
    truth, real = pairs.mask.numpy(), pairs.source_mask.numpy()
    precision = float(((t_mask & truth).sum(1) / t_mask.sum(1)).mean())
    removed = float((~s_mask & ~real).sum() / max((~real).sum(), 1))
    return precision, removed


# Floors for the shipped refinemask_scans v1.0 on 40 seeded pairs of the bundled sample,
# 0.02 (precision) and 0.05 (outliers removed) under what it measured there: clean at 5 deg
# 0.981, 10% outliers at 5 deg precision 0.965 and 0.747 removed (its card: 0.981, 0.965,
# 0.719 on 300 test pairs). The rule measured 0.969, 0.946 and 0.599 on the same pairs.
def test_shipped_refinement_weights_keep_their_accuracy(shipped_pairs):
    from masknet.registration.stages.refinement import NearestNeighbourMasks

    net = RefineMaskNet.pretrained()
    clean, _ = _masks_at(net, shipped_pairs["clean"], 5.0)
    precision, removed = _masks_at(net, shipped_pairs["outliers"], 5.0)
    assert clean >= 0.96 and precision >= 0.945 and removed >= 0.70
    # and it beats the rule where the card says it does: outliers, a residual of 5 degrees
    rule_precision, rule_removed = _masks_at(
        NearestNeighbourMasks(), shipped_pairs["outliers"], 5.0
    )
    assert precision > rule_precision and removed > rule_removed + 0.05

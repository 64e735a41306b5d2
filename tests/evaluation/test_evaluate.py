"""Seeded evaluation: the realigned-mask row agrees with the plain one where it must."""

from __future__ import annotations

import numpy as np
import pytest

from masknet import register
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.evaluation.evaluate import evaluate_masknet, realigned_mask_metrics

pytestmark = pytest.mark.usefixtures("one_thread")


def test_round_one_is_the_plain_top_k_mask(small_masknet):
    points = load_modelnet40(bundled_sample_path()).points
    result = evaluate_masknet(small_masknet, points, num_pairs=12, seed=3, progress=False)
    pairs = make_test_pairs(points, 12, PairConfig(), seed=3)
    first = realigned_mask_metrics(small_masknet, pairs, rounds=1)
    assert first == pytest.approx(result.rows["top-k (k=M)"], abs=1e-6)


def test_realigned_rounds_add_a_row(small_masknet):
    points = load_modelnet40(bundled_sample_path()).points
    result = evaluate_masknet(
        small_masknet, points, num_pairs=6, seed=3, progress=False, realign_rounds=2
    )
    row = result.rows["top-k, round 2 of mask -> Mask-ICP"]
    assert set(row) == {"precision", "recall", "f1", "iou"}
    # The row, computed here: the masks of a two-round register call, scored pair by pair.
    pairs = make_test_pairs(points, 6, PairConfig(), seed=3)
    masks = register(
        pairs.template.double().numpy(),
        pairs.source.double().numpy(),
        method="icp",
        iterations=2,
        model=small_masknet,
        precision="fp32",
        max_iterations=30,
    ).mask
    truth = pairs.mask.numpy()
    hits = (masks & truth).sum(1)
    precision, recall = hits / masks.sum(1), hits / truth.sum(1)
    expected = {
        "precision": precision.mean(),
        "recall": recall.mean(),
        "f1": (2 * precision * recall / (precision + recall)).mean(),
        "iou": (hits / (masks | truth).sum(1)).mean(),
    }
    assert row == pytest.approx(expected, abs=1e-6)
    # Round 2 masks at the pose round 1 reached: measured 0.871 against round 1's 0.688
    # (the random network, at chance); twice round 2's shortfall (0.742) fails.
    assert row["precision"] > 0.8 > result.rows["top-k (k=M)"]["precision"]


def test_per_pair_precision_matches_the_mean(small_masknet):
    points = load_modelnet40(bundled_sample_path()).points
    result = evaluate_masknet(small_masknet, points, num_pairs=10, seed=4, progress=False)
    per_pair = result.topk_precision
    assert per_pair.shape == (10,) and np.all((0 <= per_pair) & (per_pair <= 1))
    assert per_pair.mean() == pytest.approx(result.rows["top-k (k=M)"]["precision"], abs=1e-6)
    expected = per_pair.std(ddof=1) / np.sqrt(10)
    assert result.topk_precision_stderr == pytest.approx(expected) and expected > 0
    assert result.to_dict()["topk_precision_stderr"] == pytest.approx(expected)

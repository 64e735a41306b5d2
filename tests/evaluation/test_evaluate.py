"""Seeded evaluation: the realigned-mask row agrees with the plain one where it must."""

from __future__ import annotations

import numpy as np
import pytest

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
    assert set(row) == {"precision", "recall", "f1", "iou"} and 0 <= row["precision"] <= 1


def test_per_pair_precision_matches_the_mean(small_masknet):
    points = load_modelnet40(bundled_sample_path()).points
    result = evaluate_masknet(small_masknet, points, num_pairs=10, seed=4, progress=False)
    per_pair = result.topk_precision
    assert per_pair.shape == (10,) and np.all((0 <= per_pair) & (per_pair <= 1))
    assert per_pair.mean() == pytest.approx(result.rows["top-k (k=M)"]["precision"], abs=1e-6)
    expected = per_pair.std(ddof=1) / np.sqrt(10)
    assert result.topk_precision_stderr == pytest.approx(expected) and expected > 0
    assert result.to_dict()["topk_precision_stderr"] == pytest.approx(expected)

"""Tests for masknet.metrics on hand-made masks."""

from __future__ import annotations

import pytest
import torch

from masknet.metrics import MaskMetrics, mask_metrics


def _mask(bits: str) -> torch.Tensor:
    return torch.tensor([c == "1" for c in bits])


def test_known_counts():
    # truth has 4 inliers; prediction: 3 TP, 1 FP, 1 FN (pred size 4 = truth size 4).
    pred = _mask("11110000")
    truth = _mask("11101000")
    m = mask_metrics(pred[None], truth[None])
    assert isinstance(m, MaskMetrics)
    assert m.precision.shape == (1,)
    torch.testing.assert_close(m.precision, torch.tensor([3 / 4]))
    torch.testing.assert_close(m.recall, torch.tensor([3 / 4]))
    torch.testing.assert_close(m.f1, torch.tensor([6 / 8]))
    torch.testing.assert_close(m.iou, torch.tensor([3 / 5]))


def test_recall_uses_real_false_negatives():
    # TP = 2, FP = 1, FN = 3: |pred| = 3 differs from |truth| = 5.
    pred = _mask("1100100000")
    truth = _mask("1111010000")
    m = mask_metrics(pred[None], truth[None])
    torch.testing.assert_close(m.precision, torch.tensor([2 / 3]))
    torch.testing.assert_close(m.recall, torch.tensor([2 / 5]))
    torch.testing.assert_close(m.f1, torch.tensor([4 / 8]))
    torch.testing.assert_close(m.iou, torch.tensor([2 / 6]))
    assert m.recall[0] != m.precision[0]
    # F1 is the harmonic mean of precision and recall.
    p, r = m.precision[0], m.recall[0]
    torch.testing.assert_close(m.f1[0], 2 * p * r / (p + r))


def test_batched_rows_are_independent():
    pred = torch.stack([_mask("1111"), _mask("1000"), _mask("0000"), _mask("0110")])
    truth = torch.stack([_mask("1111"), _mask("1100"), _mask("1010"), _mask("1001")])
    m = mask_metrics(pred, truth)
    torch.testing.assert_close(m.precision, torch.tensor([1.0, 1.0, 0.0, 0.0]))
    torch.testing.assert_close(m.recall, torch.tensor([1.0, 0.5, 0.0, 0.0]))
    torch.testing.assert_close(m.f1, torch.tensor([1.0, 2 / 3, 0.0, 0.0]))
    torch.testing.assert_close(m.iou, torch.tensor([1.0, 0.5, 0.0, 0.0]))
    means = m.mean()
    assert set(means) == {"precision", "recall", "f1", "iou"}
    assert means["precision"] == pytest.approx(0.5)
    assert means["recall"] == pytest.approx(0.375)


def test_empty_prediction_gives_zero_precision():
    m = mask_metrics(_mask("0000")[None], _mask("0110")[None])
    assert m.precision.item() == 0.0
    assert m.recall.item() == 0.0
    assert m.f1.item() == 0.0
    assert m.iou.item() == 0.0
    assert torch.isfinite(torch.stack(list(m))).all()


def test_empty_truth_and_prediction_are_zero_not_nan():
    m = mask_metrics(_mask("000")[None], _mask("000")[None])
    assert all(v.item() == 0.0 for v in m)


def test_accepts_non_bool_masks():
    pred = torch.tensor([[1.0, 0.0, 1.0, 0.0]])
    truth = torch.tensor([[1, 1, 0, 0]])
    m = mask_metrics(pred, truth)
    torch.testing.assert_close(m.precision, torch.tensor([0.5]))
    torch.testing.assert_close(m.recall, torch.tensor([0.5]))

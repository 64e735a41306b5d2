"""Evaluation: mask metrics and seeded benchmarks."""

from masknet.evaluation.metrics import MaskMetrics, mask_metrics

__all__ = ["MaskMetrics", "mask_metrics"]

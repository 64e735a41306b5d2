"""Evaluation: mask metrics and seeded benchmarks."""

from masknet.metrics import MaskMetrics, mask_metrics

__all__ = ["MaskMetrics", "mask_metrics"]

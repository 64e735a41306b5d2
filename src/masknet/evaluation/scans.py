"""MaskNet and Mask-X on pairs cut from real scans (:mod:`masknet.data.scans`).

The pairs are sensor-like views of unit-radius crops (independent sampling, visibility,
noise in proportion to the crop's radius), so translation errors are in crop radii.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from masknet.data.scans import Scan, ScanCropConfig, make_scan_test_pairs
from masknet.data.views import ViewConfig
from masknet.evaluation.evaluate import MaskEvaluation, evaluate_pairs
from masknet.evaluation.registration import PIPELINES, benchmark_registration
from masknet.models.masknet import MaskNet

__all__ = ["SCAN_PIPELINES", "ScanEvaluation", "evaluate_scans"]

# X against Mask-X on real-scan pairs.
SCAN_PIPELINES = {name: PIPELINES[name] for name in ("ICP", "Mask-ICP", "Mask-ICP, 3 rounds")}


@dataclass
class ScanEvaluation:
    """Mask metrics over all pairs (``mask.rows``), top-k precision per scan, and
    registration errors per pipeline (rotation in degrees, translation in crop radii)."""

    mask: MaskEvaluation
    scans: list[str]
    per_scan: dict[str, float] = field(default_factory=dict)
    registration: dict[str, dict[str, float]] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return self.mask.to_dict() | {
            "scans": self.scans,
            "topk_precision_per_scan": self.per_scan,
            "registration": self.registration,
        }


def evaluate_scans(
    model: MaskNet,
    scans: Sequence[Scan],
    pairs_per_scan: int = 50,
    seed: int = 0,
    view: ViewConfig | None = None,
    crop: ScanCropConfig | None = None,
    precision: str = "fp32",
    pipelines: Mapping[str, dict] | None = SCAN_PIPELINES,
    progress: bool = True,
) -> ScanEvaluation:
    """Score ``pairs_per_scan`` seeded pairs cut from each scan; register them too
    unless ``pipelines`` is None or empty.

    The same (scans, pairs_per_scan, seed, view, crop) always gives the same pairs.
    """
    view = view or ViewConfig()
    crop = crop or ScanCropConfig()
    pairs, names = make_scan_test_pairs(scans, pairs_per_scan, view, crop, seed)
    settings = {"view": view.to_dict(), "crop": {"crop_points": list(crop.crop_points)}}
    mask = evaluate_pairs(model, pairs, seed, settings, precision, progress=progress)
    per_pair = mask.topk_precision
    per_scan = {s.name: float(per_pair[np.array(names) == s.name].mean()) for s in scans}
    registration = (
        benchmark_registration(
            pairs, pipelines, progress=progress, model=model, precision=precision
        )
        if pipelines
        else {}
    )
    return ScanEvaluation(mask, [s.name for s in scans], per_scan, registration)

"""``denoising``: outlier removal by MaskNet, the distance-to-template rule and Open3D's filters."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from masknet.data.pairs import PairConfig
from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.experiments.pipelines import shipped_masknet
from masknet.experiments.plots import line_plot, series_by
from masknet.metrics import outlier_removal_metrics


def run(ctx: BenchmarkContext) -> ExperimentResult:
    """Outlier removal at 5, 10 and 20% uniform outliers: MaskNet (when its denoising
    weights ship), the distance-to-template rule and Open3D's filters."""
    from masknet.denoising import (
        denoise,
        open3d_radius_outlier_removal,
        open3d_statistical_outlier_removal,
    )

    model = shipped_masknet("denoise_modelnet40")
    rows = []
    for ratio in [0.05, 0.1, 0.2]:
        # Aligned pairs, as the denoiser was trained (denoise after registration).
        pairs = ctx.test_pairs(
            PairConfig(outlier_ratio=ratio, max_angle_deg=0.0, max_translation=0.0)
        )
        noisy, truth = pairs.source.numpy(), pairs.source_mask.numpy()
        templates = pairs.template.numpy()
        methods = {
            "template distance (3x spacing)": np.stack(
                [
                    denoise(t, c, method="distance").mask
                    for t, c in zip(templates, noisy, strict=True)
                ]
            ),
            "Open3D statistical (20 nn, 2 std)": np.stack(
                [open3d_statistical_outlier_removal(c) for c in noisy]
            ),
            "Open3D radius (8 pts in 0.1)": np.stack(
                [open3d_radius_outlier_removal(c) for c in noisy]
            ),
        }
        if model is not None:
            scores = model.predict(noisy, templates, normalize=False)  # unit-radius shapes
            methods = {"MaskNet denoise (threshold 0.5)": scores >= 0.5} | methods
        for name, kept in methods.items():
            rows.append({"outliers": ratio, "method": name, **outlier_removal_metrics(kept, truth)})

    def plot(path: Path) -> None:
        lines = {}
        precision = series_by(rows, "outlier_precision", by="method")
        recall = series_by(rows, "outlier_recall", by="method")
        for n in precision:
            lines[f"{n}: precision"] = precision[n]
            lines[f"{n}: recall"] = recall[n]
        line_plot(
            path,
            [5, 10, 20],
            lines,
            "outliers (% of source points)",
            "outlier removal",
            "Denoising",
        )

    summary = (
        f"{ctx.pairs} pairs per rate: 30% missing source plus uniform outliers in its bounding "
        "box, aligned with the template (no motion: denoising comes after registration); "
        "precision/recall of the removed points as outliers, and the share of real points kept."
    )
    return ExperimentResult(rows, summary, plot)

"""``outliers``: registration error against uniform source outliers, 0-20%."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from masknet.data.pairs import PairConfig, Pairs
from masknet.errors import MaskNetWarning
from masknet.evaluation.registration import batched_errors, error_summary, pair_arrays
from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.experiments.pipelines import SWEEP_PIPELINES, shipped_masknet
from masknet.experiments.plots import line_plot, series_by
from masknet.geometry.clouds import MIN_POINTS
from masknet.registration.api import register


def register_denoise_register(pairs: Pairs, how: dict, kwargs: dict) -> dict[str, float]:
    """Errors of register -> denoise the moved source (``how``: denoise() arguments) ->
    register again, pair by pair."""
    from masknet.denoising import denoise

    templates, sources, truth = pair_arrays(pairs)
    estimates = np.empty_like(truth)
    skipped = 0
    for i in range(len(truth)):
        template, source = templates[i], sources[i]
        first = register(template, source, **kwargs).transform
        moved = source @ first[:3, :3].T + first[:3, 3]
        with warnings.catch_warnings():  # a first pass far off is handled below
            warnings.simplefilter("ignore", MaskNetWarning)
            cleaned = denoise(template, moved, **how).points
        if len(cleaned) < MIN_POINTS:
            # A first pass far off leaves almost nothing near the template, too few points
            # for register(): keep its estimate.
            estimates[i] = first
            skipped += 1
        else:
            estimates[i] = register(template, cleaned, **kwargs).transform @ first
    return error_summary(estimates, truth) | {"second_pass_skipped": skipped}


def run(ctx: BenchmarkContext) -> ExperimentResult:
    """Registration error against uniform source outliers, 0-20%: X, Mask-X with the shipped
    MaskNet, Mask-X with the MaskNet trained with 10% source outliers (the paper's), and
    Mask-X -> denoise the moved source -> Mask-X again."""
    denoiser = shipped_masknet("denoise_modelnet40")
    outlier_model = shipped_masknet("modelnet40_outliers10")
    how = {"method": "masknet", "model": denoiser} if denoiser else {"method": "distance"}
    ratios = [0.0, 0.1, 0.2] if ctx.quick else [0.0, 0.05, 0.1, 0.15, 0.2]
    count = ctx.pairs if not ctx.quick else min(ctx.pairs, 10)
    pipelines = dict(SWEEP_PIPELINES)
    if outlier_model is not None:
        for name in ("Mask-ICP", "Mask-PointNetLK"):
            pipelines[f"{name} (MaskNet trained with 10% outliers)"] = {
                **SWEEP_PIPELINES[name],
                "model": outlier_model,
            }
    rows = []
    for ratio in ratios:
        pairs = ctx.test_pairs(PairConfig(outlier_ratio=ratio), count=count)
        for name, kwargs in pipelines.items():
            key = {"outliers": ratio, "pipeline": name}
            rows.append(ctx.row(key, batched_errors, pairs, **kwargs))
        for name in ("Mask-ICP", "Mask-PointNetLK"):
            key = {"outliers": ratio, "pipeline": f"{name}, denoise ({how['method']}), {name}"}
            rows.append(ctx.row(key, register_denoise_register, pairs, how, SWEEP_PIPELINES[name]))

    def plot(path: Path) -> None:
        line_plot(
            path,
            [100 * r for r in ratios],
            series_by(rows, "rot_mean"),
            "outliers (% of source points)",
            "mean rotation error (degrees)",
            "Outliers",
        )

    summary = (
        f"{count} pairs per rate, 30% missing, <= 45 deg; Mask-X uses the shipped MaskNet"
        + (
            ", and the rows marked '(MaskNet trained with 10% outliers)' the MaskNet fine-tuned "
            "with 10% source outliers "
            "(`MaskNet.pretrained('modelnet40_outliers10')`)."
            if outlier_model is not None
            else " (no outlier-trained MaskNet ships)."
        )
        + (
            f" The 'denoise' rows register, drop the source points the denoiser rejects and "
            f"register again; `second_pass_skipped` counts the pairs where fewer than "
            f"{MIN_POINTS} points survived, so the first estimate stands."
        )
    )
    return ExperimentResult(rows, summary, plot)

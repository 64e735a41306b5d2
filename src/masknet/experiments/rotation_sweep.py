"""``rotation-sweep``: errors against the initial rotation, 0-90 degrees, for X and Mask-X."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from masknet.data.pairs import PairConfig, Pairs
from masknet.evaluation.registration import batched_errors
from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.experiments.pipelines import sweep_pipelines
from masknet.experiments.plots import line_plot, series_by
from masknet.geometry.se3 import invert_transform, make_transform, so3_exp


def rotated_by(pairs: Pairs, angle_deg: float, seed: int) -> Pairs:
    """Pairs made without rotation, turned by exactly ``angle_deg`` about random axes.

    The source (P, M, 3) is rotated about the origin, and the truth (P, 4, 4) updated so
    that ``template ~= T @ source`` still holds.
    """
    gen = torch.Generator().manual_seed(seed)
    b = pairs.template.shape[0]
    axes = torch.randn(b, 3, generator=gen, dtype=torch.float64)
    rot = so3_exp(axes / axes.norm(dim=-1, keepdim=True) * np.radians(angle_deg))
    source = pairs.source.double() @ rot.transpose(1, 2)
    moving = make_transform(rot, torch.zeros(b, 3, dtype=torch.float64))
    truth = pairs.transform.double() @ invert_transform(moving)
    return pairs._replace(source=source.float(), transform=truth.float())


def run(ctx: BenchmarkContext) -> ExperimentResult:
    """Errors against the initial rotation, 0-90 degrees, for X and Mask-X."""
    angles = [0, 45, 90] if ctx.quick else list(range(0, 91, 10))
    base = ctx.test_pairs(PairConfig(max_angle_deg=0.0))
    sweep = sweep_pipelines()
    rows = []
    for angle in angles:
        pairs = rotated_by(base, angle, ctx.seed + angle)
        for name, kwargs in sweep.items():
            rows.append(
                ctx.row({"angle_deg": angle, "pipeline": name}, batched_errors, pairs, **kwargs)
            )

    def plot(path: Path) -> None:
        line_plot(
            path,
            angles,
            series_by(rows, "rot_mean", names=list(sweep)),
            "initial rotation (degrees)",
            "mean rotation error (degrees)",
            "Rotation sweep",
        )

    return ExperimentResult(
        rows, f"{ctx.pairs} pairs per angle, 30% missing, translation in [-1, 1]^3.", plot
    )

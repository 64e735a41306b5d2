"""``timing``: milliseconds per pair at batch 1 for X and Mask-X."""

from __future__ import annotations

import platform

import torch

from masknet.evaluation.registration import time_pipeline, x_and_mask_x
from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.experiments.pipelines import sweep_pipelines
from masknet.runtime import default_precision

# The paper's Table (GTX 1070), ms per pair: X, Mask-X.
PAPER_TIMING_MS = {
    "ICP": (6.82, 9.83),
    "PointNetLK": (52.30, 58.15),
    "DCP": (23.99, 24.68),
    "PRNet": (68.52, 82.18),
}


def run(ctx: BenchmarkContext) -> ExperimentResult:
    """Milliseconds per pair at batch 1 for X and Mask-X, median of many calls."""
    pairs = ctx.test_pairs(count=8)
    repeats = 5 if ctx.quick else 100
    rows = []
    pipelines = sweep_pipelines() | x_and_mask_x({"ICP (Open3D backend)": "open3d-icp"})
    for label, kwargs in pipelines.items():
        method = label.removeprefix("Mask-").removesuffix(" (Open3D backend)")
        paper = PAPER_TIMING_MS.get(method, (float("nan"),) * 2)[label.startswith("Mask-")]
        rows.append(
            {
                "pipeline": label,
                **time_pipeline(pairs, repeats, **kwargs),
                "paper_gtx1070_ms": paper,
            }
        )
    summary = (
        f"batch 1, N=1024, M=717, median of {repeats} single-pair register() calls after 5 "
        f"warm-up calls, {torch.get_num_threads()} threads, {platform.machine()} CPU, "
        f"torch {torch.__version__}; MaskNet in {default_precision('cpu')} (the default)."
    )
    return ExperimentResult(rows, summary)

"""``networks``: the learned back-ends (DCP, PRNet, PCRNet, RPM-Net), X against Mask-X."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from masknet._extras import progress_bar
from masknet.data.pairs import Pairs
from masknet.evaluation.registration import (
    batched_errors,
    error_summary,
    time_pipeline,
    x_and_mask_x,
)
from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.experiments.pipelines import LEARNED, shipped
from masknet.experiments.plots import error_bars


def _row(pairs: Pairs, timing_pairs: Pairs, repeats: int, kwargs: dict) -> dict:
    """Errors over ``pairs`` (batched) and batch-1 times over ``timing_pairs``."""
    return batched_errors(pairs, **kwargs) | time_pipeline(
        timing_pairs, repeats, warmup=2, **kwargs
    )


def run(ctx: BenchmarkContext) -> ExperimentResult:
    """The learned back-ends (DCP, PRNet, PCRNet, RPM-Net): X against Mask-X, and no motion."""
    pairs = ctx.test_pairs()
    truth = pairs.transform.double().numpy()
    identity = np.broadcast_to(np.eye(4), truth.shape)
    rows = [{"pipeline": "Identity (no motion)", **error_summary(identity, truth)}]
    missing = [name for name, method in LEARNED.items() if not shipped(method)]
    pipelines = x_and_mask_x({n: m for n, m in LEARNED.items() if n not in missing})
    timing_pairs = pairs.rows(slice(8))
    repeats = 3 if ctx.quick else 20
    for name, kwargs in progress_bar(pipelines.items(), desc="networks", disable=not ctx.progress):
        rows.append(ctx.row({"pipeline": name}, _row, pairs, timing_pairs, repeats, kwargs))
    for row in rows:
        for key in ("ms_per_pair", "ms_mask", "ms_register"):
            row.setdefault(key, float("nan"))

    def plot(path: Path) -> None:
        error_bars(path, rows, f"Learned back-ends on {len(pairs.template)} ModelNet40 test pairs")

    summary = (
        f"{len(pairs.template)} pairs, the registration experiment's (same seed): 30% missing, "
        "rotation <= 45 deg, translation in [-1, 1]^3; each network at its paper's iteration "
        "count (DCP 1, PRNet 3, PCRNet 8, RPM-Net 5) with the shipped weights; X uses the "
        "whole template, Mask-X the template points MaskNet keeps. Errors from batched calls; "
        f"times: median of {repeats} single-pair register() calls (batch 1) after 2 warm-ups."
        + (f" Not shipped, so not run: {', '.join(missing)}." if missing else "")
    )
    return ExperimentResult(rows, summary, plot)

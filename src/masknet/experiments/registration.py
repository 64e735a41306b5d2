"""``registration``: X against Mask-X (and refinements) on the default protocol, pair by pair."""

from __future__ import annotations

from pathlib import Path

from masknet.data.pairs import Pairs
from masknet.evaluation.registration import PIPELINES, benchmark_registration
from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.experiments.plots import error_bars


def _row(pairs: Pairs, name: str, kwargs: dict, progress: bool) -> dict:
    return benchmark_registration(pairs, {name: kwargs}, progress=progress)[name]


def run(ctx: BenchmarkContext) -> ExperimentResult:
    """X against Mask-X (and refinements) on the default protocol, pair by pair."""
    pairs = ctx.test_pairs()
    rows = [
        ctx.row({"pipeline": name}, _row, pairs, name, kwargs, ctx.progress)
        for name, kwargs in PIPELINES.items()
    ]
    best = min(rows, key=lambda r: r["rot_median"])

    def plot(path: Path) -> None:
        error_bars(
            path,
            rows,
            f"Registration on {len(pairs.template)} ModelNet40 test pairs (30% missing, <=45 deg)",
        )

    summary = (
        f"{len(pairs.template)} pairs, 30% missing, rotation <= 45 deg, translation in [-1, 1]^3; "
        f"lowest median rotation error: {best['pipeline']} ({best['rot_median']:.2f} deg)."
    )
    return ExperimentResult(rows, summary, plot)

"""``iterations``: errors after each round of mask -> register -> move the source."""

from __future__ import annotations

from pathlib import Path

from masknet.data.pairs import Pairs
from masknet.evaluation.registration import iteration_errors
from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.experiments.plots import line_plot


def _row(pairs: Pairs, method: str, progress: bool) -> dict:
    return {"rounds": iteration_errors(pairs, 3, progress=progress, method=method)}


def run(ctx: BenchmarkContext) -> ExperimentResult:
    """Errors after each round of mask -> register -> move the source."""
    pairs = ctx.test_pairs()
    rows = []
    for name, method in (("Mask-ICP", "icp"), ("Mask-PointNetLK", "pointnetlk")):
        kept = ctx.row({"pipeline": name}, _row, pairs, method, ctx.progress)
        rows += [{"pipeline": name, **row} for row in kept["rounds"]]

    def plot(path: Path) -> None:
        lines = {
            f"{name} ({stat})": [r[f"rot_{stat}"] for r in rows if r["pipeline"] == name]
            for name in ("Mask-ICP", "Mask-PointNetLK")
            for stat in ("mean", "median")
        }
        line_plot(
            path,
            [1, 2, 3],
            lines,
            "round",
            "rotation error (degrees)",
            "Iterative mask -> register",
        )

    return ExperimentResult(rows, f"{len(pairs.template)} pairs, default protocol, 3 rounds.", plot)

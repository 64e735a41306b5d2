"""``iterations``: errors after each round of mask -> register -> move the source.

Two loops on the same pairs, for ICP and PointNetLK: the paper's (its MaskNet in every
round, each cloud centred on its own centroid) and the refined loop that
``register(..., method=X, iterations=3)`` runs (the two-sided network in round 1,
refinement masks on the pair as it stands in rounds >= 2). The paired difference of
the rotation errors, with its standard error, says whether the refined loop is better
pair by pair.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from masknet.data.pairs import Pairs
from masknet.evaluation.registration import pair_arrays, paired_difference, pose_errors
from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.experiments.plots import line_plot
from masknet.models.masknet import MaskNet
from masknet.registration.api import register

__all__ = ["per_round_errors", "run"]

ROUNDS = 3


def per_round_errors(pairs: Pairs, **kwargs: object) -> np.ndarray:
    """(ROUNDS, P) rotation errors in degrees after each round of ``register``."""
    template, source, truth = pair_arrays(pairs)
    per_round = np.empty((ROUNDS, *truth.shape))
    for i in range(len(truth)):
        result = register(template[i], source[i], iterations=ROUNDS, **kwargs)
        per_round[:, i] = np.stack(result.rounds)
    return np.stack([pose_errors(per_round[r], truth)[0] for r in range(ROUNDS)])


def _rows(pairs: Pairs, method: str) -> dict:
    paper = per_round_errors(
        pairs, method=method, model=MaskNet.pretrained(), refine_masks="network"
    )
    refined = per_round_errors(pairs, method=method)
    out = []
    for r in range(ROUNDS):
        for loop, errors in (("paper's loop", paper[r]), ("refined loop", refined[r])):
            row = {
                "loop": loop,
                "round": r + 1,
                "rot_mean": float(errors.mean()),
                "rot_median": float(np.median(errors)),
                "rot_p90": float(np.percentile(errors, 90)),
            }
            if loop == "refined loop":
                row |= paired_difference(errors, paper[r])
            out.append(row)
    return {"rounds": out}


def run(ctx: BenchmarkContext) -> ExperimentResult:
    """Errors after each round: the paper's loop against the refined loop, paired."""
    pairs = ctx.test_pairs()
    rows = []
    for name, method in (("Mask-ICP", "icp"), ("Mask-PointNetLK", "pointnetlk")):
        kept = ctx.row({"pipeline": name}, _rows, pairs, method)
        rows += [{"pipeline": name, **row} for row in kept["rounds"]]

    def plot(path: Path) -> None:
        lines = {
            f"{name}, {loop}": [
                r["rot_mean"] for r in rows if r["pipeline"] == name and r["loop"] == loop
            ]
            for name in ("Mask-ICP", "Mask-PointNetLK")
            for loop in ("paper's loop", "refined loop")
        }
        line_plot(path, [1, 2, 3], lines, "round", "mean rotation error (degrees)", "Rounds")

    summary = (
        f"{len(pairs.template)} pairs, default protocol, 3 rounds. The paper's loop runs its "
        "MaskNet in every round; the refined loop is register(..., method=X, iterations=3) with "
        "its defaults. paired_diff: refined minus paper, mean over the pairs, with its standard "
        "error (negative: the refined loop is better)."
    )
    return ExperimentResult(rows, summary, plot)

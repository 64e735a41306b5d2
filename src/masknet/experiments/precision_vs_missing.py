"""``precision-vs-missing``: MaskNet's top-k precision as the missing fraction grows."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from masknet.data.pairs import PairConfig, Pairs
from masknet.evaluation.evaluate import PAIRS_PER_CALL, evaluate_masknet
from masknet.evaluation.registration import pair_arrays
from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.experiments.pipelines import LEARNED, shipped
from masknet.experiments.plots import line_plot
from masknet.models.masknet import MaskNet
from masknet.registration.api import register


def correspondence_precision(pairs: Pairs, method: str, chunk: int = PAIRS_PER_CALL) -> float:
    """Mean per-pair precision of a network's correspondence inliers (pairs with none: 0)."""
    template, source, _ = pair_arrays(pairs)
    truth = pairs.mask.numpy()
    precisions = []
    for i in range(0, len(template), chunk):
        result = register(
            template[i : i + chunk], source[i : i + chunk], method=method, use_mask=False
        )
        called = result.correspondence_inliers
        hits = (called & truth[i : i + chunk]).sum(1)
        precisions.append(hits / np.maximum(called.sum(1), 1))
    return float(np.concatenate(precisions).mean())


def run(ctx: BenchmarkContext) -> ExperimentResult:
    """MaskNet's top-k precision as the missing fraction grows (trained at 30%)."""
    model = MaskNet.pretrained()
    missing = [0.1, 0.3, 0.5] if ctx.quick else [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]
    correspondence = [n for n in ("PRNet", "RPM-Net") if shipped(LEARNED[n])]

    def precisions(miss: float) -> dict:
        config = PairConfig(keep_ratio=1 - miss)
        result = evaluate_masknet(model, ctx.points, ctx.pairs, ctx.seed, config, progress=False)
        top = result.rows["top-k (k=M)"]
        row = {"precision": top["precision"], "recall": top["recall"], "chance": 1 - miss}
        pairs = ctx.test_pairs(config)
        for name in correspondence:
            row[f"{name} precision"] = correspondence_precision(pairs, LEARNED[name])
        return row

    rows = [ctx.row({"missing": miss}, precisions, miss) for miss in missing]

    def plot(path: Path) -> None:
        lines = {"MaskNet top-k precision": [r["precision"] for r in rows]}
        for name in correspondence:
            lines[f"{name} correspondence precision"] = [r[f"{name} precision"] for r in rows]
        line_plot(
            path,
            [100 * r["missing"] for r in rows],
            lines,
            "missing points (%)",
            "inlier precision",
            "MaskNet precision vs missing points",
            baseline=("chance (random top-k)", [r["chance"] for r in rows]),
        )

    summary = f"{ctx.pairs} pairs per point, rotation <= 45 deg." + (
        f" {' and '.join(correspondence)}: the share of template points in a confident "
        "correspondence (see RegistrationResult.correspondence_inliers) that are true inliers, "
        "the network on the whole template (no mask)."
        if correspondence
        else ""
    )
    return ExperimentResult(rows, summary, plot)

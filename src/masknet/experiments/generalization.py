"""``generalization``: the MaskNet trained on the first 20 categories, on seen and unseen shapes."""

from __future__ import annotations

from masknet.data.pairs import PairConfig, make_test_pairs
from masknet.evaluation.evaluate import evaluate_masknet
from masknet.evaluation.registration import batched_errors
from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.models.masknet import MaskNet


def run(ctx: BenchmarkContext) -> ExperimentResult:
    """The model trained on the first 20 categories, on seen and unseen test shapes."""
    model = MaskNet.pretrained("modelnet40_seen20")
    rows = []
    for subset, keep in (("seen", ctx.categories < 20), ("unseen", ctx.categories >= 20)):
        points = ctx.points[keep]
        mask_result = evaluate_masknet(model, points, ctx.pairs, ctx.seed, progress=False)
        pairs = make_test_pairs(points, ctx.pairs, PairConfig(), ctx.seed)
        errors = batched_errors(pairs, method="pointnetlk", model=model)
        rows.append(
            {
                "categories": subset,
                "precision": mask_result.rows["top-k (k=M)"]["precision"],
                **errors,
            }
        )
    return ExperimentResult(
        rows, f"{ctx.pairs} pairs per subset; Mask-PointNetLK with the seen-20 MaskNet."
    )

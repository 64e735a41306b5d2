"""Seeded mask-quality evaluation of MaskNet on a fixed set of pairs."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from masknet._extras import progress_bar
from masknet.data.pairs import PairConfig, Pairs, make_test_pairs
from masknet.metrics import MaskMetrics, mask_metrics
from masknet.models.masknet import PAIRS_PER_CALL, MaskNet, select_mask

__all__ = [
    "MaskEvaluation",
    "evaluate_masknet",
    "evaluate_pairs",
    "format_table",
    "realigned_mask_metrics",
    "score_pairs",
    "PAIRS_PER_CALL",
]


@dataclass
class MaskEvaluation:
    """Mean metrics over the test pairs.

    rows: selection rule -> {"precision", "recall", "f1", "iou"} means. Rules are
    ``top-k (k=M)``, ``threshold 0.5`` and ``random top-k`` (a seeded baseline
    that picks M template points at random).
    topk_precision: (P,) float64, the top-k precision of each pair, for standard
    errors and paired comparisons of two models on the same pairs.
    """

    pairs: int
    seed: int
    pair_config: dict
    precision_mode: str
    rows: dict[str, dict[str, float]] = field(default_factory=dict)
    ms_per_pair: float = 0.0
    topk_precision: np.ndarray | None = None
    scores: np.ndarray | None = None
    pairs_data: Pairs | None = None

    @property
    def topk_precision_stderr(self) -> float:
        """Standard error of the mean top-k precision over the pairs (nan for < 2 pairs)."""
        p = self.topk_precision
        if p is None or len(p) < 2:
            return float("nan")
        return float(p.std(ddof=1) / np.sqrt(len(p)))

    def to_dict(self) -> dict:
        return {
            "pairs": self.pairs,
            "seed": self.seed,
            "pair_config": self.pair_config,
            "inference_precision": self.precision_mode,
            "metrics": self.rows,
            "topk_precision_stderr": self.topk_precision_stderr,
            "ms_per_pair_batched": self.ms_per_pair,
        }


def score_pairs(
    model: MaskNet,
    pairs: Pairs,
    precision: str = "fp32",
    batch_size: int = PAIRS_PER_CALL,
    progress: bool = False,
) -> torch.Tensor:
    """MaskNet's inference-path scores (P, N) float32 on CPU for every pair, in batches."""
    fused = model.scorer(precision)
    device = next(model.parameters()).device
    total = pairs.template.shape[0]
    scores = []
    for i in progress_bar(
        range(0, total, batch_size), desc="evaluating", disable=not progress, leave=False
    ):
        t = pairs.template[i : i + batch_size].to(device)
        s = pairs.source[i : i + batch_size].to(device)
        scores.append(fused(t, s).float().cpu())
    return torch.cat(scores)


def evaluate_masknet(
    model: MaskNet,
    points: np.ndarray,
    num_pairs: int = 1000,
    seed: int = 0,
    pair_config: PairConfig | None = None,
    precision: str = "fp32",
    threshold: float = 0.5,
    batch_size: int = PAIRS_PER_CALL,
    progress: bool = True,
    keep_outputs: bool = False,
    realign_rounds: int = 0,
) -> MaskEvaluation:
    """Score ``num_pairs`` seeded pairs made from shapes (S, N, 3).

    The same (points, num_pairs, seed, pair_config) always gives the same pairs,
    so different models are compared on identical data. ``keep_outputs`` keeps the
    pairs and scores on the result (for pictures and further analysis).
    ``realign_rounds`` > 1 adds the row ``top-k, round R of mask -> Mask-ICP``
    (:func:`realigned_mask_metrics`).
    """
    pair_config = pair_config or PairConfig()
    pairs = make_test_pairs(points, num_pairs, pair_config, seed)
    return evaluate_pairs(
        model,
        pairs,
        seed,
        pair_config.to_dict(),
        precision,
        threshold,
        batch_size,
        progress,
        keep_outputs,
        realign_rounds,
    )


def evaluate_pairs(
    model: MaskNet,
    pairs: Pairs,
    seed: int = 0,
    pair_config: dict | None = None,
    precision: str = "fp32",
    threshold: float = 0.5,
    batch_size: int = PAIRS_PER_CALL,
    progress: bool = True,
    keep_outputs: bool = False,
    realign_rounds: int = 0,
) -> MaskEvaluation:
    """:func:`evaluate_masknet` on given pairs (any generator's); ``pair_config`` is
    recorded as given, and ``seed`` seeds the random baseline."""
    num_pairs = pairs.template.shape[0]
    start = time.perf_counter()
    all_scores = score_pairs(model, pairs, precision, batch_size, progress)
    elapsed = time.perf_counter() - start
    m = pairs.source.shape[1]
    random_scores = torch.rand(all_scores.shape, generator=torch.Generator().manual_seed(seed))
    rules: dict[str, MaskMetrics] = {
        "top-k (k=M)": mask_metrics(select_mask(all_scores, k=m), pairs.mask),
        f"threshold {threshold:g}": mask_metrics(
            select_mask(all_scores, threshold=threshold), pairs.mask
        ),
        "random top-k": mask_metrics(select_mask(random_scores, k=m), pairs.mask),
    }
    rows = {name: metrics.mean() for name, metrics in rules.items()}
    if realign_rounds > 1:
        rows[f"top-k, round {realign_rounds} of mask -> Mask-ICP"] = realigned_mask_metrics(
            model, pairs, realign_rounds, precision=precision, progress=progress
        )
    return MaskEvaluation(
        pairs=num_pairs,
        seed=seed,
        pair_config=pair_config or {},
        precision_mode=precision,
        rows=rows,
        ms_per_pair=1000 * elapsed / num_pairs,
        topk_precision=rules["top-k (k=M)"].precision.double().numpy(),
        scores=all_scores.numpy() if keep_outputs else None,
        pairs_data=pairs if keep_outputs else None,
    )


def realigned_mask_metrics(
    model: MaskNet,
    pairs: Pairs,
    rounds: int,
    max_iterations: int = 30,
    precision: str = "fp32",
    chunk: int = PAIRS_PER_CALL,
    progress: bool = False,
) -> dict[str, float]:
    """Mean metrics of the top-k mask predicted after ``rounds - 1`` Mask-ICP alignments.

    Round r predicts the mask for the source as moved by rounds 1..r-1 (mask -> Mask-ICP
    with ``max_iterations`` -> move the source), as ``register(iterations=rounds)`` does:
    once the source is nearly aligned the network's task is easier. This measures
    MaskNet inside that pipeline, not the network alone.
    """
    from masknet.registration.api import register

    template, source = pairs.template.double().numpy(), pairs.source.double().numpy()
    masks = []
    for i in progress_bar(range(0, len(template), chunk), desc="realigning", disable=not progress):
        result = register(
            template[i : i + chunk],
            source[i : i + chunk],
            method="icp",  # Mask-ICP's rounds, with their max_iterations
            iterations=rounds,
            model=model,
            precision=precision,
            max_iterations=max_iterations,
        )
        masks.append(torch.from_numpy(result.mask))
    return mask_metrics(torch.cat(masks), pairs.mask).mean()


def format_table(rows: dict[str, dict[str, float]]) -> str:
    """A plain-text table: one row per selection rule, mean metric per column."""
    columns = ["precision", "recall", "f1", "iou"]
    width = max(len(name) for name in rows) + 2
    lines = ["selection".ljust(width) + "".join(c.rjust(11) for c in columns)]
    lines.append("-" * len(lines[0]))
    for name, values in rows.items():
        lines.append(name.ljust(width) + "".join(f"{values[c]:11.4f}" for c in columns))
    return "\n".join(lines)

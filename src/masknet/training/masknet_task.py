"""The MaskNet training task: pairs, loss (MSE or BCE) and top-k precision."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from torch import Tensor, nn

from masknet.data.pairs import PairConfig, Pairs, iterate_pairs, make_test_pairs
from masknet.evaluation.metrics import mask_metrics
from masknet.models.masknet import MaskNet, select_mask

__all__ = ["MaskNetTask"]


@dataclass
class MaskNetTask:
    """Train MaskNet to score template points seen by the source.

    num_points: template points per training pair (a fresh random subset of each
        shape every epoch when smaller than the stored 1,024).
    loss: ``"mse"`` (the paper's) or ``"bce"``.
    model_config: keyword arguments of :class:`MaskNet` (default: the paper's sizes).
    """

    pairs: PairConfig = field(default_factory=PairConfig)
    num_points: int = 1024
    loss: Literal["mse", "bce"] = "mse"
    model_config: dict = field(default_factory=dict)
    name: str = "masknet"
    metric: str = "precision"

    def build_model(self) -> nn.Module:
        return MaskNet(**self.model_config)

    def train_batches(self, points: np.ndarray, batch_size: int, seed: int, epoch: int):
        return iterate_pairs(
            points, self.pairs, batch_size, seed, epoch, self.num_points, drop_last=True
        )

    def val_batches(
        self, points: np.ndarray, num_pairs: int, batch_size: int, seed: int
    ) -> list[Pairs]:
        # Validation always uses the full stored resolution, like the test set.
        pairs = make_test_pairs(points, num_pairs, self.pairs, seed=seed + 7919)
        return [
            Pairs(*(x[i : i + batch_size] for x in pairs))
            for i in range(0, len(pairs.template), batch_size)
        ]

    def step(
        self, model: nn.Module, batch: Pairs, device: torch.device
    ) -> tuple[Tensor, dict[str, float]]:
        scores = model(batch.template.to(device), batch.source.to(device)).float()
        target = batch.mask.to(device).float()
        if self.loss == "mse":
            loss = nn.functional.mse_loss(scores, target)
        else:
            loss = nn.functional.binary_cross_entropy(scores.clamp(1e-6, 1 - 1e-6), target)
        with torch.no_grad():
            predicted = select_mask(scores, k=batch.source.shape[1])
            metrics = mask_metrics(predicted, target.bool()).mean()
        return loss, {"precision": metrics["precision"], "recall": metrics["recall"]}

    def export(self, model: nn.Module, path: Path, metadata: dict) -> None:
        model.save(path, metadata)

    def describe(self) -> dict:
        return {
            "model": dict(self.model_config),
            "name": self.name,
            "pairs": self.pairs.to_dict(),
            "num_points": self.num_points,
            "loss": self.loss,
        }

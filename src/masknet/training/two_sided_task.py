"""Training the two-sided MaskNet: the real-scan task's pairs, corrupted in the source.

:class:`TwoSidedTask` takes every batch of :class:`ScanMaskNetTask` (ModelNet40 pairs,
sensor-like ModelNet40 views and pairs cut from real scans) and puts noise, uniform
outliers and clutter into its source (:mod:`masknet.data.corruption`), each pair
drawing its own amounts. The loss is BCE on the source scores against ``source_mask``.
The encoder and the template branch start from a shipped MaskNet and stay frozen
(:class:`~masknet.models.two_sided.TwoSidedMaskNet`), so only the source branch learns.

Metrics: the source mask at score 0.5 (``f1``, ``outliers_removed``: the fraction of
corrupted points rejected, ``inliers_kept``), and in validation the template mask's
top-k precision with k = M, as at inference (``template_precision``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor, nn

from masknet.data.corruption import CorruptionConfig, corrupt_source
from masknet.data.pairs import Pairs
from masknet.metrics import mask_metrics
from masknet.models.masknet import MaskNet, select_mask
from masknet.models.two_sided import TwoSidedMaskNet
from masknet.models.weights import read_metadata
from masknet.training.scan_task import MappedEpoch, ScanMaskNetTask, by_kind

__all__ = ["TwoSidedTask", "outliers_removed"]


def outliers_removed(kept: Tensor, truth: Tensor) -> float:
    """The share of the corrupted source points (``truth`` False) that the source mask
    ``kept`` rejects, over a batch (B, M); 0 where none is corrupted."""
    return float((~kept & ~truth).sum() / (~truth).sum().clamp_min(1))


@dataclass
class TwoSidedTask(ScanMaskNetTask):
    """See the module docstring.

    corruption: what goes into the sources.
    init: the shipped MaskNet weights the encoder and template branch start from
        (a name for :meth:`MaskNet.pretrained`, or a MaskNet file), a two-sided network's
        file to fine-tune, or "" for random weights.
    """

    corruption: CorruptionConfig = field(default_factory=CorruptionConfig)
    init: str = "modelnet40"
    name: str = "masknet2"
    metric: str = "f1"
    loss: str = "bce"

    def __post_init__(self) -> None:
        if not self.scans:  # ModelNet40 alone
            self.scan_batches = 0
            return
        super().__post_init__()

    def build_model(self) -> nn.Module:
        if not self.init:
            return TwoSidedMaskNet(**self.model_config)
        two_sided_key = TwoSidedMaskNet._config_key()
        if self.init.endswith(".safetensors") and two_sided_key in read_metadata(self.init):
            return TwoSidedMaskNet.from_file(self.init)  # fine-tuning a two-sided network
        if self.init.endswith(".safetensors"):
            masknet = MaskNet.from_file(self.init)
        else:
            masknet = MaskNet.pretrained(self.init)
        return TwoSidedMaskNet.from_masknet(masknet, **self.model_config)

    def train_batches(self, points: np.ndarray, batch_size: int, seed: int, epoch: int):
        return MappedEpoch(
            super().train_batches(points, batch_size, seed, epoch), self._corrupt, seed, epoch, 0xC0
        )

    def val_batches(
        self, points: np.ndarray, num_pairs: int, batch_size: int, seed: int
    ) -> list[Pairs]:
        batches = super().val_batches(points, num_pairs, batch_size, seed)
        return list(MappedEpoch(batches, self._corrupt, seed + 7919, 0xBA1, 0xC0))

    def _corrupt(self, batch: Pairs, generator: torch.Generator) -> Pairs:
        return corrupt_source(batch, self.corruption, generator)

    def step(
        self, model: nn.Module, batch: Pairs, device: torch.device
    ) -> tuple[Tensor, dict[str, float]]:
        template, source = batch.template.to(device), batch.source.to(device)
        truth = batch.source_mask.to(device)
        template_logits, source_logits = model(
            template, source, logits=True, template_branch=not model.training
        )
        loss = nn.functional.binary_cross_entropy_with_logits(source_logits.float(), truth.float())
        with torch.no_grad():
            kept = source_logits >= 0
            m = mask_metrics(kept, truth).mean()
            metrics = {
                "f1": m["f1"],
                "outliers_removed": outliers_removed(kept, truth),
                "inliers_kept": float((kept & truth).sum() / truth.sum().clamp_min(1)),
            }
            if not model.training:
                # k = M, as TwoSidedMaskNet.predict_masks selects at inference.
                selected = select_mask(template_logits.float(), k=source.shape[1])
                metrics["template_precision"] = float(
                    mask_metrics(selected, batch.mask.to(device)).mean()["precision"]
                )
        return loss, by_kind(batch, metrics)

    def describe_extra(self) -> dict:
        return super().describe_extra() | {
            "corruption": self.corruption.to_dict(),
            "init": self.init,
        }

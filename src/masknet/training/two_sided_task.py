"""Training the two-sided MaskNet: the real-scan mix's pairs, corrupted in the source.

:class:`TwoSidedTask` takes every batch of its :class:`~masknet.training.scan_mix.ScanMix`
(ModelNet40 pairs, sensor-like ModelNet40 views and pairs cut from real scans; without
scans, the first two) and puts noise, uniform
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
from typing import Literal

import torch
from torch import Tensor, nn

from masknet.data.corruption import CorruptionConfig, corrupt_source
from masknet.data.pairs import Pairs
from masknet.metrics import mask_metrics
from masknet.models.masknet import MaskNet, select_mask
from masknet.models.two_sided import TwoSidedMaskNet
from masknet.models.weights import read_metadata
from masknet.training.pair_task import PairTask
from masknet.training.scan_mix import BatchChange, ScanMix, by_kind

__all__ = ["TwoSidedTask", "corrupting", "outliers_removed"]


def outliers_removed(kept: Tensor, truth: Tensor) -> float:
    """The share of the corrupted source points (``truth`` False) that the source mask
    ``kept`` rejects, over a batch (B, M); 0 where none is corrupted."""
    return float((~kept & ~truth).sum() / (~truth).sum().clamp_min(1))


def corrupting(corruption: CorruptionConfig) -> BatchChange:
    """The step that puts ``corruption`` into every batch's source (tag 0xC0)."""

    def corrupt(batch: Pairs, generator: torch.Generator) -> Pairs:
        return corrupt_source(batch, corruption, generator)

    return BatchChange(corrupt, 0xC0, 7919)


@dataclass
class TwoSidedTask(PairTask):
    """See the module docstring.

    mix: the batches' sources (default: ModelNet40 pairs and views, no scans).
    corruption: what goes into the sources.
    init: the shipped MaskNet weights the encoder and template branch start from
        (a name for :meth:`MaskNet.pretrained`, or a MaskNet file), a two-sided network's
        file to fine-tune, or "" for random weights.
    model_config: keyword arguments of :class:`TwoSidedMaskNet`.
    """

    mix: ScanMix | None = field(default_factory=lambda: ScanMix(scan_batches=0))
    corruption: CorruptionConfig = field(default_factory=CorruptionConfig)
    init: str = "modelnet40"
    model_config: dict = field(default_factory=dict)
    name: str = "masknet2"
    metric: str = "f1"
    maximize: bool = True
    loss: Literal["bce"] = "bce"

    def batch_changes(self) -> tuple[BatchChange, ...]:
        return (corrupting(self.corruption),)

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
        return {"loss": self.loss, "corruption": self.corruption.to_dict(), "init": self.init}

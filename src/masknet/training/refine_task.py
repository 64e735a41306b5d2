"""Training the refinement mask: the two-sided task's pairs, as a registration round leaves them.

:class:`RefineMaskTask` takes the two-sided task's batches (its
:class:`~masknet.training.scan_mix.ScanMix`: ModelNet40 pairs, sensor-like ModelNet40 views
and pairs cut from real scans, with noise, outliers and clutter put in the source; template
and source sampled independently wherever the view generator cuts them), moves each source
onto its template by the true pose and off it
again by a residual drawn from :class:`~masknet.data.residuals.ResidualConfig`
(:func:`~masknet.data.residuals.residual_pairs`). The loss is BCE on both masks.

Metrics: template precision and recall at score 0.5 (``template_precision``,
``template_recall``), the source mask's F1 and the share of corrupted source points
rejected (``source_f1``, ``outliers_removed``), and ``score``, the mean of the template
precision and the source F1, which picks the best weights.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Literal

import torch
from torch import Tensor, nn

from masknet.data.corruption import CorruptionConfig
from masknet.data.pairs import Pairs
from masknet.data.residuals import ResidualConfig, residual_pairs
from masknet.errors import MaskNetError
from masknet.metrics import mask_metrics
from masknet.models.refine import RefineMaskNet
from masknet.training.pair_task import PairTask
from masknet.training.scan_mix import BatchChange, ScanMix, by_kind
from masknet.training.two_sided_task import corrupting, outliers_removed

__all__ = ["RefineMaskTask"]


@dataclass
class RefineMaskTask(PairTask):
    """See the module docstring.

    mix: the batches' sources (default: ModelNet40 pairs, half of them sampled
        independently as views; no scans).
    corruption: what goes into the sources (as the two-sided task's).
    residual: the residual poses the sources are moved by.
    init: a refinement-mask file to fine-tune, or "".
    model_config: keyword arguments of :class:`RefineMaskNet`.
    """

    mix: ScanMix | None = field(
        default_factory=lambda: ScanMix(scan_batches=0, modelnet_view_fraction=0.5)
    )
    corruption: CorruptionConfig = field(default_factory=CorruptionConfig)
    residual: ResidualConfig = field(default_factory=ResidualConfig)
    init: str = ""
    model_config: dict = field(default_factory=dict)
    name: str = "refinemask"
    metric: str = "score"
    maximize: bool = True
    loss: Literal["bce"] = "bce"

    def batch_changes(self) -> tuple[BatchChange, ...]:
        def move(batch: Pairs, generator: torch.Generator) -> Pairs:
            return residual_pairs(batch, self.residual, generator)

        return (corrupting(self.corruption), BatchChange(move, 0x2E5, 104729))

    def build_model(self) -> nn.Module:
        if self.init:
            model = RefineMaskNet.from_file(self.init)
            widen = not model.config.get("context")  # v1.0 weights: a context stage may be added
            # Fine-tuning keeps the file's architecture, compared as JSON stores it (a tuple
            # of channels is the file's list).
            asked = json.loads(json.dumps(self.model_config))
            clash = {
                key: value
                for key, value in asked.items()
                if model.config.get(key) != value and not (key == "context" and widen)
            }
            if clash:
                raise MaskNetError(
                    f"--model-config {json.dumps(clash)} differs from the --init weights "
                    f"({json.dumps({k: model.config.get(k) for k in clash})}): fine-tuning "
                    "keeps their architecture (only a context stage can be added to weights "
                    "without one)"
                )
            if widen and asked.get("context"):
                return model.with_context(asked["context"])
            return model
        return RefineMaskNet(**self.model_config)

    def step(
        self, model: nn.Module, batch: Pairs, device: torch.device
    ) -> tuple[Tensor, dict[str, float]]:
        template, source = batch.template.to(device), batch.source.to(device)
        truth_t, truth_s = batch.mask.to(device), batch.source_mask.to(device)
        t_logits, s_logits = model(template, source, logits=True)
        bce = nn.functional.binary_cross_entropy_with_logits
        loss = bce(t_logits.float(), truth_t.float()) + bce(s_logits.float(), truth_s.float())
        with torch.no_grad():
            t = mask_metrics(t_logits >= 0, truth_t).mean()
            s = mask_metrics(s_logits >= 0, truth_s).mean()
            metrics = {
                "template_precision": t["precision"],
                "template_recall": t["recall"],
                "source_f1": s["f1"],
                "outliers_removed": outliers_removed(s_logits >= 0, truth_s),
                "score": (t["precision"] + s["f1"]) / 2,
            }
        return loss, by_kind(batch, metrics)

    def describe_extra(self) -> dict:
        return {
            "loss": self.loss,
            "corruption": self.corruption.to_dict(),
            "init": self.init,
            "residual": self.residual.to_dict(),
        }

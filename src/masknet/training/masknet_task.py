"""The MaskNet training task: pairs, loss (MSE or BCE) and top-k precision."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import torch
from torch import Tensor, nn

from masknet.data.pairs import PairConfig, Pairs
from masknet.metrics import mask_metrics
from masknet.models.cross_masknet import CrossMaskNet
from masknet.models.masknet import MaskNet, select_mask
from masknet.training.pair_task import PairTask
from masknet.training.scan_mix import ScanMix, by_kind

__all__ = ["MASK_NETWORKS", "MaskNetTask"]

# The template-mask networks by name, as ``MaskNetTask(network=...)`` and ``masknet train
# --model`` take them.
MASK_NETWORKS = {"masknet": MaskNet, "crossmasknet": CrossMaskNet}


@dataclass
class MaskNetTask(PairTask):
    """Train MaskNet to score template points seen by the source.

    pairs, num_points: see :class:`PairTask` (default: the paper's protocol).
    loss: ``"mse"`` (the paper's) or ``"bce"``.
    network: which mask network: ``"masknet"`` (the paper's) or ``"crossmasknet"``
        (:class:`~masknet.models.CrossMaskNet`: local geometry and cross-attention).
    model_config: keyword arguments of that network's class (default: its own sizes).
    role: ``"template"`` (the paper's main use: score template points seen by the
        source, top-k precision) or ``"denoise"`` (score the points of a source
        with outliers, given the clean template; threshold 0.5, F1 of the kept points).
        Use :meth:`denoising` for the denoising task's defaults.
    mix: real scans mixed in (:class:`~masknet.training.scan_mix.ScanMix`); metrics are
        then logged per kind of batch too. :meth:`on_scans` names such a run.
    teacher: distil a (smaller) network from this frozen MaskNet (shipped name or
        ``.safetensors`` file): the BCE target is ``distill_weight`` times the teacher's
        score plus the rest times the true label (``loss="bce"`` only).
    distill_weight: the teacher's share of the target, in [0, 1].
    """

    loss: Literal["mse", "bce"] = "mse"
    network: Literal["masknet", "crossmasknet"] = "masknet"
    model_config: dict = field(default_factory=dict)
    name: str = "masknet"
    metric: str = "precision"
    maximize: bool = True
    role: Literal["template", "denoise"] = "template"
    teacher: str | None = None
    distill_weight: float = 0.5

    def __post_init__(self) -> None:
        if self.teacher is not None and self.loss != "bce":
            raise ValueError("distilling from a teacher needs loss='bce'")
        if self.network not in MASK_NETWORKS:
            raise ValueError(
                f"network must be one of {sorted(MASK_NETWORKS)}, got {self.network!r}"
            )
        if not 0.0 <= self.distill_weight <= 1.0:
            raise ValueError(f"distill_weight must lie in [0, 1], got {self.distill_weight}")

    @classmethod
    def denoising(cls, pairs: PairConfig, **kwargs) -> MaskNetTask:
        """The paper's denoising task: outliers in the source, masks predicted for it.

        The network centres both clouds on the clean template's centroid
        (``centring="source"``, unless ``model_config`` says otherwise): denoising works on
        aligned clouds, and centring a partial, outlier-ridden cloud on its own centroid would
        throw their relative position away.
        """
        config = {"centring": "source", **kwargs.pop("model_config", {})}
        return cls(
            pairs=pairs,
            role="denoise",
            metric="f1",
            name="masknet-denoise",
            model_config=config,
            **kwargs,
        )

    @classmethod
    def on_scans(cls, mix: ScanMix, **kwargs) -> MaskNetTask:
        """MaskNet trained on ModelNet40 and real scans: the batches of ``mix``."""
        kwargs.setdefault("name", "masknet-scans")
        return cls(mix=mix, **kwargs)

    def build_model(self) -> nn.Module:
        return MASK_NETWORKS[self.network](**self.model_config)

    def step(
        self, model: nn.Module, batch: Pairs, device: torch.device
    ) -> tuple[Tensor, dict[str, float]]:
        if self.role == "denoise":
            scored, given = batch.source.to(device), batch.template.to(device)
            target = batch.source_mask.to(device).float()
        else:
            scored, given = batch.template.to(device), batch.source.to(device)
            target = batch.mask.to(device).float()
        if self.loss == "mse":
            scores = model(scored, given).float()
            loss = nn.functional.mse_loss(scores, target)
        else:
            # BCE on logits: a sigmoid saturated at the wrong answer (a start from weights
            # that keep everything) still gets a gradient of 1, where BCE on clamped
            # scores gets none.
            logits = model(scored, given, logits=True).float()
            soft = target if self.teacher is None else self._soft_target(scored, given, target)
            loss = nn.functional.binary_cross_entropy_with_logits(logits, soft)
            scores = torch.sigmoid(logits)
        with torch.no_grad():
            if self.role == "denoise":
                predicted = scores >= 0.5
            else:
                predicted = select_mask(scores, k=batch.source.shape[1])
            metrics = mask_metrics(predicted, target.bool()).mean()
        keys = ("precision", "recall", "f1") if self.role == "denoise" else ("precision", "recall")
        metrics = {key: metrics[key] for key in keys}
        return loss, metrics if self.mix is None else by_kind(batch, metrics)

    def _soft_target(self, scored: Tensor, given: Tensor, target: Tensor) -> Tensor:
        """(B, N): the true labels blended with the frozen teacher's scores."""
        teacher = getattr(self, "_teacher", None)
        if teacher is None:
            from masknet.training.registration_task import load_mask_network

            teacher = self._teacher = load_mask_network(self.teacher).to(scored.device)
        with torch.no_grad():
            scores = torch.sigmoid(teacher(scored, given, logits=True).float())
        return self.distill_weight * scores + (1.0 - self.distill_weight) * target

    def describe_extra(self) -> dict:
        extra = {"loss": self.loss} | ({"role": self.role} if self.role != "template" else {})
        if self.network != "masknet":  # only then: earlier runs' settings stay as they were
            extra["network"] = self.network
        if self.teacher is not None:
            extra |= {"teacher": self.teacher, "distill_weight": self.distill_weight}
        return extra

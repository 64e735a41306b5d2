"""The PointNetLK training task: full-cloud pairs, transform and feature losses."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor, nn

from masknet.data.pairs import PairConfig, Pairs
from masknet.geometry.se3 import invert_transform, rotation_error_deg
from masknet.models.pointnetlk import PointNetLK
from masknet.training.pair_task import PairTask

__all__ = ["PointNetLKTask"]


def _full_clouds() -> PairConfig:
    return PairConfig(keep_ratio=1.0)


@dataclass
class PointNetLKTask(PairTask):
    """Train PointNetLK as its paper does: on full clouds (``keep_ratio=1``).

    The loss is ``||T_est T_gt^-1 - I||_F^2`` (the transform error, zero only for
    the exact transform) plus ``feature_weight`` times the squared norm of the last
    feature residual, averaged over the batch; gradients flow through every LK
    iteration and through the finite-difference Jacobian.

    iterations: LK iterations per training pair (the paper's 10).
    model_config: keyword arguments of :class:`PointNetLK`.
    """

    pairs: PairConfig = field(default_factory=_full_clouds)
    iterations: int = 10
    feature_weight: float = 1.0
    model_config: dict = field(default_factory=dict)
    name: str = "pointnetlk"
    metric: str = "rotation_error_deg"
    maximize: bool = False

    def build_model(self) -> nn.Module:
        return PointNetLK(**self.model_config)

    def step(
        self, model: nn.Module, batch: Pairs, device: torch.device
    ) -> tuple[Tensor, dict[str, float]]:
        dtype = next(model.parameters()).dtype  # float32, or float64 for exact tests
        template = batch.template.to(device, dtype)
        source = batch.source.to(device, dtype)
        truth = batch.transform.to(device, dtype)
        solution = model(template, source, max_iterations=self.iterations)
        estimate = solution.transform
        eye = torch.eye(4, device=device, dtype=dtype)
        transform_loss = (estimate @ invert_transform(truth) - eye).square().sum((1, 2)).mean()
        feature_loss = solution.residual.square().mean()
        loss = transform_loss + self.feature_weight * feature_loss
        with torch.no_grad():
            error = rotation_error_deg(estimate[:, :3, :3].double(), truth[:, :3, :3].double())
        return loss, {
            "rotation_error_deg": error.mean().item(),
            "transform_loss": transform_loss.item(),
        }

    def describe_extra(self) -> dict:
        return {"iterations": self.iterations, "feature_weight": self.feature_weight}

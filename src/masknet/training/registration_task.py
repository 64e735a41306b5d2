"""The training task of every learned registration network (PointNetLK, DCP, PRNet,
PCRNet, RPM-Net): seeded pairs, a transform loss, and the network's own regulariser.

With ``template_mask`` set, the network trains on what it sees inside Mask-X: the
template points a frozen MaskNet keeps (top-k, k = M) against the partial source.
A max-pooled feature such as PointNetLK's is changed by the few points a mask gets
wrong; training on the mask's own mistakes teaches the features to ignore them."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor, nn

from masknet.data.pairs import PairConfig, Pairs
from masknet.geometry.se3 import invert_transform, rotation_error_deg
from masknet.models import REGISTRATION_NETWORKS
from masknet.training.pair_task import PairTask

__all__ = ["RegistrationTask", "TRAINING_DEFAULTS"]

# Per network: the keep ratio of its paper's training pairs (1.0 = full clouds;
# PRNet and RPM-Net were made for partial ones) and the iterations per training pair.
TRAINING_DEFAULTS = {
    "pointnetlk": {"keep_ratio": 1.0, "iterations": 10},
    "dcp": {"keep_ratio": 1.0, "iterations": 1},
    "pcrnet": {"keep_ratio": 1.0, "iterations": 3},
    "prnet": {"keep_ratio": 0.7, "iterations": 2},
    "rpmnet": {"keep_ratio": 0.7, "iterations": 2},
}


@dataclass
class RegistrationTask(PairTask):
    """Train one of :data:`masknet.models.REGISTRATION_NETWORKS` by its ``name``.

    The loss is ``||T_est T_gt^-1 - I||_F^2`` (zero only for the exact transform),
    averaged over the batch, plus ``auxiliary_weight`` times the network's own
    ``auxiliary_loss`` (PointNetLK: the squared feature residual, weight 1; RPM-Net: the
    inlier loss, weight 0.01; the others: none). Gradients flow through every iteration.

    name: the network, a key of REGISTRATION_NETWORKS.
    iterations: refinement iterations per training pair.
    model_config: keyword arguments of the network's class.
    template_mask: None (the whole template, the papers' training), or the MaskNet whose
        top-k mask picks the template points the network is given (a shipped name such
        as ``"modelnet40"``, or a ``.safetensors`` file): Mask-X training.
    """

    name: str = "pointnetlk"
    iterations: int = 10
    model_config: dict = field(default_factory=dict)
    metric: str = "rotation_error_deg"
    maximize: bool = False
    template_mask: str | None = None

    @classmethod
    def for_network(cls, name: str, pairs: PairConfig | None = None, **kwargs) -> RegistrationTask:
        """A task with the network's training defaults (:data:`TRAINING_DEFAULTS`)."""
        defaults = TRAINING_DEFAULTS[name]
        pairs = pairs or PairConfig(keep_ratio=defaults["keep_ratio"])
        kwargs.setdefault("iterations", defaults["iterations"])
        return cls(pairs=pairs, name=name, **kwargs)

    @property
    def auxiliary_weight(self) -> float:
        return getattr(REGISTRATION_NETWORKS[self.name], "auxiliary_weight", 1.0)

    def build_model(self) -> nn.Module:
        return REGISTRATION_NETWORKS[self.name](**self.model_config)

    def step(
        self, model: nn.Module, batch: Pairs, device: torch.device
    ) -> tuple[Tensor, dict[str, float]]:
        dtype = next(model.parameters()).dtype  # float32, or float64 for exact tests
        template = batch.template.to(device, dtype)
        source = batch.source.to(device, dtype)
        truth = batch.transform.to(device, dtype)
        if self.template_mask is not None:
            template = self._masked_template(batch).to(device, dtype)
        solution = model(template, source, max_iterations=self.iterations)
        estimate = solution.transform.to(dtype)
        eye = torch.eye(4, device=device, dtype=dtype)
        transform_loss = (estimate @ invert_transform(truth) - eye).square().sum((1, 2)).mean()
        loss = transform_loss + self.auxiliary_weight * solution.auxiliary_loss
        with torch.no_grad():
            error = rotation_error_deg(estimate[:, :3, :3].double(), truth[:, :3, :3].double())
        return loss, {
            "rotation_error_deg": error.mean().item(),
            "transform_loss": transform_loss.item(),
        }

    def _masked_template(self, batch: Pairs) -> Tensor:
        """(B, M, 3): the template points the frozen MaskNet keeps for each pair."""
        network = getattr(self, "_mask_network", None)
        if network is None:
            network = load_mask_network(self.template_mask)
            self._mask_network = network
        mask = network.predict_mask(batch.template.numpy(), batch.source.numpy())
        index = torch.from_numpy(np.stack([np.flatnonzero(m) for m in mask]))
        return torch.gather(batch.template, 1, index[..., None].expand(-1, -1, 3))

    def describe_extra(self) -> dict:
        extra = {"iterations": self.iterations, "auxiliary_weight": self.auxiliary_weight}
        if self.template_mask is not None:
            extra["template_mask"] = self.template_mask
        return extra


def load_mask_network(name: str) -> nn.Module:
    """A frozen MaskNet in eval mode: shipped weights by name, or a ``.safetensors`` file."""
    from pathlib import Path

    from masknet.models import MaskNet

    if Path(name).suffix == ".safetensors" or Path(name).exists():
        network = MaskNet.from_file(name)
    else:
        network = MaskNet.pretrained(name)
    return network.eval().requires_grad_(False)

"""Iterative PCRNet (Sarode et al., 2019): PointNet features, a pose regressed by an MLP.

Each iteration embeds both clouds with one shared PointNet (max-pooled, no
BatchNorm so a cloud's feature depends on that cloud alone), concatenates the two
global features and regresses a pose with fully connected layers 1024-1024-512-512-256-7:
a quaternion (w, x, y, z), normalised, and a translation. The moved source is fed back
for the next iteration (the paper's 8 at test time), and poses compose.
Clouds are centred first (:func:`centred_registration`).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from masknet.geometry.se3 import make_transform, quaternion_to_rotation
from masknet.models.layers import RegistrationSolution, centred_registration, he_init
from masknet.models.pointnet import PointNetEncoder
from masknet.models.weights import SafetensorsWeights

__all__ = ["PCRNet"]


class PCRNet(SafetensorsWeights, nn.Module):
    """Iterative PCRNet: forward(template (B, N, 3), source (B, M, 3)) -> RegistrationSolution.

    Args:
        encoder_channels: PointNet widths, the last is the feature size K (paper: 1,024).
        head_channels: the pose regressor's hidden widths (paper: 1024, 1024, 512, 512, 256).
        input_points: the cloud size the network was trained at; :func:`masknet.register`
            farthest-point samples larger clouds to it (the source in proportion). None:
            any size as given.
    """

    weights_prefix = "pcrnet_"
    default_iterations = 8

    def __init__(
        self,
        encoder_channels: Sequence[int] = (64, 64, 64, 128, 1024),
        head_channels: Sequence[int] = (1024, 1024, 512, 512, 256),
        input_points: int | None = None,
    ):
        super().__init__()
        self.config = {
            "input_points": input_points,
            "encoder_channels": list(encoder_channels),
            "head_channels": list(head_channels),
        }
        self.encoder = PointNetEncoder(encoder_channels, batch_norm=False)
        dims = [2 * encoder_channels[-1], *head_channels]
        layers: list[nn.Module] = []
        for a, b in zip(dims[:-1], dims[1:], strict=True):
            layers += [nn.Linear(a, b), nn.ReLU()]
        he_init([*self.encoder.linears, *layers])  # no normalisation layers here
        last = nn.Linear(dims[-1], 7)
        # Start at the identity pose: zero weights, bias = unit quaternion, zero translation.
        nn.init.zeros_(last.weight)
        with torch.no_grad():
            last.bias.copy_(torch.tensor([1.0, 0, 0, 0, 0, 0, 0]))
        self.head = nn.Sequential(*layers, last)

    def pose(self, template: Tensor, source: Tensor) -> Tensor:
        """The regressed transform (B, 4, 4) of ``source`` onto ``template``."""
        features = torch.cat([self.encoder(template).amax(1), self.encoder(source).amax(1)], -1)
        out = self.head(features)
        return make_transform(quaternion_to_rotation(out[:, :4]), out[:, 4:])

    def _step(self, template: Tensor, source: Tensor, _: int):
        return self.pose(template, source), None, template.new_zeros(())

    def forward(
        self, template: Tensor, source: Tensor, max_iterations: int = 8
    ) -> RegistrationSolution:
        """Register ``source`` (B, M, 3) to ``template`` (B, N, 3); see the module docs."""
        return centred_registration(template, source, self._step, max_iterations)

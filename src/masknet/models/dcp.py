"""DCP, Deep Closest Point (Wang & Solomon, ICCV 2019), the DCP-v2 variant.

1. A DGCNN embeds each cloud: per-point features F_X (B, N, C), F_Y (B, M, C).
2. Attention conditions each cloud's features on the other's (:class:`CrossAttention`).
3. Every source point i gets a soft correspondence in the template,
   ``y_i = sum_j softmax_j(phi_s_i . phi_t_j / sqrt(C)) t_j``.
4. A differentiable SVD (:func:`masknet.geometry.rigid_align`) fits the rigid
   transform source -> {y_i}.

Clouds are centred first (:func:`centred_registration`); ``max_iterations > 1``
repeats steps 1-4 on the moved source (DCP itself runs once).
"""

from __future__ import annotations

from collections.abc import Sequence

from torch import Tensor, nn

from masknet.geometry.align import rigid_align
from masknet.geometry.se3 import make_transform
from masknet.models.layers import (
    CrossAttention,
    EdgeConvEncoder,
    RegistrationSolution,
    centred_registration,
    soft_assignment,
)
from masknet.models.weights import SafetensorsWeights

__all__ = ["DCP"]


class DCP(SafetensorsWeights, nn.Module):
    """DCP-v2: forward(template (B, N, 3), source (B, M, 3)) -> :class:`RegistrationSolution`.

    Args:
        input_points: the cloud size the network was trained at; :func:`masknet.register`
            farthest-point samples larger clouds (the template in use to this many, the
            source in proportion) because the k-NN features depend on density. None:
            any size as given.
        channels: the DGCNN EdgeConv widths (paper: 64, 64, 128, 256).
        embedding: per-point feature size C (paper: 512).
        k: DGCNN neighbours (paper: 20).
        heads, feedforward: the attention's heads and hidden width (paper: 4, 1024).

    The shipped model's card states its own (smaller) sizes and training.
    """

    weights_prefix = "dcp_"
    default_iterations = 1

    def __init__(
        self,
        channels: Sequence[int] = (64, 64, 128, 256),
        embedding: int = 512,
        k: int = 20,
        heads: int = 4,
        feedforward: int = 1024,
        input_points: int | None = None,
    ):
        super().__init__()
        self.config = {
            "input_points": input_points,
            "channels": list(channels),
            "embedding": embedding,
            "k": k,
            "heads": heads,
            "feedforward": feedforward,
        }
        self.encoder = EdgeConvEncoder(channels, embedding, k)
        self.attention = CrossAttention(embedding, heads, feedforward)

    def correspondences(self, template: Tensor, source: Tensor) -> Tensor:
        """Soft correspondence matrix (B, M, N): row i weighs the template points for source i."""
        phi_t, phi_s = self.attention(self.encoder(template), self.encoder(source))
        return soft_assignment(phi_s, phi_t)

    def _step(self, template: Tensor, source: Tensor, _: int):
        weights = self.correspondences(template, source)
        rotation, translation = rigid_align(source, weights @ template)
        return make_transform(rotation, translation), None, template.new_zeros(())

    def forward(
        self, template: Tensor, source: Tensor, max_iterations: int = 1
    ) -> RegistrationSolution:
        """Register ``source`` (B, M, 3) to ``template`` (B, N, 3); see the module docs."""
        return centred_registration(template, source, self._step, max_iterations)

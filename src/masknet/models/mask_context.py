"""Context for MaskNet's scores: the template point's neighbourhood and the source's points.

The paper's MaskNet scores each template point from its own PointNet feature, a function
of that point's coordinates alone, and one max-pooled vector of the source. Its mistakes
sit on the edge of the seen region, where a point's own position says least (RESULTS,
"Where Mask-PointNetLK's error comes from"). :class:`MaskContext` corrects the logits
with what a point-wise head cannot see:

1. **the template neighbourhood**: offsets to the point's ``k`` nearest template points
   (in template radii) with their first logits, through a shared MLP and a max-pool.
   An edge of the view is a place where the logits of nearby points change.
2. **the source's points**: one attention step from the template point's feature to the
   source points' features (a ``width``-channel query, keys and values), its value and
   the best similarity: whether some source point looks like this one.

The correction is residual, ``logit + delta``, and its last layer starts at zero, so a
MaskNet with context initialised from the paper's weights starts as exactly that network
and fine-tuning can only add what the context explains.

forward(template (B, N, 3) centred, template features (B, N, F), source features
(B, M, F), logits (B, N)) -> logits (B, N).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from masknet.geometry.clouds import unit_radius
from masknet.models.layers import gather_points, linear_stack, mlp, mlp_pool, neighbour_index

__all__ = ["MaskContext"]


class MaskContext(nn.Module):
    """The residual context head of :class:`masknet.models.masknet.MaskNet` (``context=k``).

    Args:
        features: F, the encoder's output width.
        k: template neighbours pooled per point.
        width: channels of the neighbourhood MLP and of the attention.
    """

    def __init__(self, features: int, k: int = 16, width: int = 64):
        super().__init__()
        self.k = k
        self.query = nn.Linear(features, width, bias=False)
        self.key = nn.Linear(features, width, bias=False)
        self.value = nn.Linear(features, width, bias=False)
        # Per neighbour: offset (3, template radii), own logit, neighbour's logit.
        self.edge = linear_stack([5, width, width])
        self.out = linear_stack([2 * width + 2, 128, 1])
        nn.init.zeros_(self.out[-1].weight)
        nn.init.zeros_(self.out[-1].bias)

    def forward(
        self, template: Tensor, template_features: Tensor, source_features: Tensor, logits: Tensor
    ) -> Tensor:
        """(B, N, 3), (B, N, F), (B, M, F), (B, N) -> corrected logits (B, N)."""
        scale = unit_radius(template)[:, None, None, None]  # (B, 1, 1, 1)
        idx = neighbour_index(template.float(), min(self.k, template.shape[1]))  # (B, N, k)
        offsets = (gather_points(template, idx) - template[:, :, None, :]) / scale
        own = logits[:, :, None, None].expand(-1, -1, idx.shape[2], 1)
        theirs = gather_points(logits[..., None], idx)
        local = mlp_pool(self.edge, torch.cat([offsets, own.to(offsets), theirs.to(offsets)], -1))
        query = self.query(template_features)
        key = self.key(source_features)
        similarity = query @ key.transpose(1, 2) / math.sqrt(query.shape[-1])  # (B, N, M)
        attended = similarity.softmax(dim=-1) @ self.value(source_features)  # (B, N, width)
        best = similarity.amax(dim=-1, keepdim=True)
        joint = torch.cat(
            [local, attended.to(local), best.to(local), logits[..., None].to(local)], -1
        )
        return logits + mlp(self.out, joint).squeeze(-1).to(logits)

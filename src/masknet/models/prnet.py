"""PRNet (Wang & Solomon, NeurIPS 2019): keypoints and Gumbel-softmax correspondences.

Each iteration:

1. DGCNN embeds both clouds and DCP's attention conditions each on the other.
2. Keypoints: the ``keypoints`` points of each cloud with the largest feature norms
   (PRNet's detector), so that matching uses points both clouds are likely to share.
3. Every source keypoint i gets a distribution p_i over the template keypoints:
   ``softmax(phi_s_i . phi_t_j / (sqrt(C) tau))`` with a temperature tau predicted
   from the two pooled embeddings; in training it is perturbed by Gumbel noise
   (a soft Gumbel-softmax sample).
4. A differentiable SVD fits source keypoints -> ``sum_j p_ij t_j``.

The moved source feeds the next iteration (the paper's 3). Clouds are centred first.
Deviations: LayerNorm for BatchNorm in the DGCNN; a soft Gumbel-softmax sample where
the paper's code takes a hard (straight-through) one; the cycle-consistency and
feature-alignment losses are left out (the transform loss alone trains it).

**Correspondence inliers** (``template_weight``): a template keypoint's weight is the
largest probability any source keypoint puts on it; other template points get 0. A
template point counts as an inlier when its weight is at least 0.5, that is, some source
keypoint picks it with at least even confidence.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn

from masknet.geometry.align import rigid_align
from masknet.geometry.se3 import make_transform
from masknet.models.dcp import DCP
from masknet.models.layers import RegistrationSolution, centred_registration, gather_points

__all__ = ["PRNet"]


class PRNet(DCP):
    """PRNet: forward(template (B, N, 3), source (B, M, 3)) -> :class:`RegistrationSolution`.

    Args:
        keypoints: keypoints per cloud (paper: 512 of 768 points); clamped to each
            cloud's size.
        dcp_options: ``channels``, ``embedding``, ``k``, ``heads``, ``feedforward``,
            ``input_points``, as :class:`~masknet.models.DCP`, with its defaults (the
            paper's: DGCNN 64-64-128-256, 512 channels, k=20).
    """

    weights_prefix = "prnet_"
    default_iterations = 3

    def __init__(self, keypoints: int = 512, **dcp_options: Any):
        super().__init__(**dcp_options)
        self.config["keypoints"] = keypoints
        self.keypoints = keypoints
        self.temperature = nn.Sequential(
            nn.Linear(2 * self.config["embedding"], 128),
            nn.ReLU(),
            nn.Linear(128, 1),
            nn.Softplus(),
        )

    def _step(self, template: Tensor, source: Tensor, _: int):
        phi_t, phi_s = self.attention(self.encoder(template), self.encoder(source))
        kt = min(self.keypoints, template.shape[1])
        ks = min(self.keypoints, source.shape[1])
        idx_t = phi_t.norm(dim=-1).topk(kt, dim=1).indices  # (B, Kt)
        idx_s = phi_s.norm(dim=-1).topk(ks, dim=1).indices
        key_t, key_s = gather_points(template, idx_t), gather_points(source, idx_s)
        feat_t, feat_s = gather_points(phi_t, idx_t), gather_points(phi_s, idx_s)
        pooled = torch.cat([phi_t.amax(1), phi_s.amax(1)], -1)
        tau = self.temperature(pooled)[:, :, None] + 1e-2  # (B, 1, 1)
        logits = feat_s @ feat_t.transpose(1, 2) / (feat_s.shape[-1] ** 0.5) / tau
        if self.training:
            probs = nn.functional.gumbel_softmax(logits, tau=1.0, dim=-1)
        else:
            probs = torch.softmax(logits, dim=-1)  # (B, Ks, Kt)
        rotation, translation = rigid_align(key_s, probs @ key_t)
        weight = template.new_zeros(template.shape[:2])
        weight = weight.scatter(1, idx_t, probs.amax(1).to(weight.dtype))
        return make_transform(rotation, translation), weight, template.new_zeros(())

    def forward(
        self, template: Tensor, source: Tensor, max_iterations: int = 3
    ) -> RegistrationSolution:
        """Register ``source`` (B, M, 3) to ``template`` (B, N, 3); see the module docs."""
        return centred_registration(template, source, self._step, max_iterations)

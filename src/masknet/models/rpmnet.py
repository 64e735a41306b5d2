"""RPM-Net (Yew & Lee, CVPR 2020): PPF features and annealed Sinkhorn soft assignment.

Each iteration:

1. Features: for every point i and its k nearest neighbours j, the input
   ``[x_i, x_j - x_i, PPF(i, j)]`` (10 numbers) goes through a shared MLP and is
   max-pooled over j, then mapped to the feature F_i. PPF is the point pair feature
   (||d||, angle(n_i, d), angle(n_j, d), angle(n_i, n_j)) of d = x_j - x_i and the
   normals n, estimated by PCA (the data has none).
2. A parameter network (a PointNet over both clouds, each point tagged with its cloud)
   predicts the inverse temperature beta and the outlier threshold alpha.
3. Matching ``m_ij = exp(-beta (||F_s_i - F_t_j||^2 - alpha))`` is normalised by
   Sinkhorn iterations with a slack row and column, so points may stay unmatched.
4. A weighted SVD fits source i -> ``sum_j m_ij t_j / sum_j m_ij`` with weight
   ``sum_j m_ij``.

The moved source feeds the next iteration (the paper trains with 2 and tests with 5);
clouds are centred first. The auxiliary loss is the paper's inlier loss, which keeps
the matching from sending everything to the slack.

Deviations: k nearest neighbours (default 24) instead of a 0.3 radius ball with up to
64 points, because it batches; normals from PCA, whose sign is arbitrary, so the PPF
uses absolute cosines of the three angles.

**Correspondence inliers** (``template_weight``): the column sums of the final matching
matrix, ``sum_i m_ij`` in [0, 1]. A template point counts as an inlier when at least half
of its mass is matched to source points (the rest goes to the slack).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from masknet.geometry.align import rigid_align
from masknet.geometry.normals import estimate_normals
from masknet.geometry.se3 import make_transform
from masknet.models.layers import (
    RegistrationSolution,
    centred_registration,
    gather_points,
    he_init,
    sinkhorn,
)
from masknet.models.pointnet import PointNetEncoder
from masknet.models.weights import SafetensorsWeights

__all__ = ["RPMNet", "point_pair_features"]


def point_pair_features(
    points: Tensor, normals: Tensor, neighbours: Tensor, neighbour_normals: Tensor
) -> Tensor:
    """Sign-free PPF (B, N, k, 4): ||d|| and |cos| of angle(n_i, d), angle(n_j, d), angle(n_i, n_j).

    points, normals (B, N, 3); neighbours, neighbour_normals (B, N, k, 3); d = x_j - x_i.
    """
    d = neighbours - points[:, :, None]
    length = d.norm(dim=-1, keepdim=True)
    unit = d / length.clamp_min(1e-9)
    n_i = normals[:, :, None].expand_as(neighbour_normals)
    return torch.cat(
        [
            length,
            (n_i * unit).sum(-1, keepdim=True).abs(),
            (neighbour_normals * unit).sum(-1, keepdim=True).abs(),
            (n_i * neighbour_normals).sum(-1, keepdim=True).abs(),
        ],
        -1,
    )


class RPMNet(SafetensorsWeights, nn.Module):
    """RPM-Net: forward(template (B, N, 3), source (B, M, 3)) -> :class:`RegistrationSolution`.

    Args:
        input_points: the cloud size the network was trained at; :func:`masknet.register`
            farthest-point samples larger clouds (the template in use to this many, the
            source in proportion) because the k-NN features depend on density. None:
            any size as given.
        features: feature size (paper: 96).
        k: neighbours per point for the features (and for the normals).
        sinkhorn_iterations: normalisation rounds per matching (paper: 5).
        parameter_channels: widths of the parameter network's PointNet.
    """

    weights_prefix = "rpmnet_"
    default_iterations = 5
    auxiliary_weight = 0.01  # the paper's weight of the inlier loss

    def __init__(
        self,
        features: int = 96,
        k: int = 24,
        sinkhorn_iterations: int = 5,
        parameter_channels: Sequence[int] = (64, 64, 64, 128, 1024),
        input_points: int | None = None,
    ):
        super().__init__()
        self.config = {
            "input_points": input_points,
            "features": features,
            "k": k,
            "sinkhorn_iterations": sinkhorn_iterations,
            "parameter_channels": list(parameter_channels),
        }
        self.k = k
        self.sinkhorn_iterations = sinkhorn_iterations
        self.local = PointNetEncoder(
            (features, features, features), in_channels=10, batch_norm=False
        )
        self.post = nn.Sequential(
            nn.Linear(features, features), nn.ReLU(), nn.Linear(features, features)
        )
        self.annealing_net = PointNetEncoder(parameter_channels, in_channels=4, batch_norm=False)
        self.annealing_head = nn.Sequential(
            nn.Linear(parameter_channels[-1], 256), nn.ReLU(), nn.Linear(256, 2), nn.Softplus()
        )
        # No normalisation layers in these MLPs: He initialisation keeps their outputs
        # dependent on the input (the last layers keep PyTorch's smaller default).
        he_init([*self.local.linears, self.post[0], *self.annealing_net.linears])

    def point_features(self, points: Tensor) -> Tensor:
        """Per-point features (B, N, features) of a cloud (B, N, 3)."""
        b, n, _ = points.shape
        k = min(self.k, n)
        normals, idx = estimate_normals(points, k)
        neighbours = gather_points(points, idx)  # (B, N, k, 3)
        ppf = point_pair_features(points, normals, neighbours, gather_points(normals, idx))
        centre = points[:, :, None].expand_as(neighbours)
        x = torch.cat([centre, neighbours - centre, ppf], -1).reshape(b, n * k, 10)
        local = self.local(x).reshape(b, n, k, -1).amax(2)
        return self.post(local)

    def annealing(self, template: Tensor, source: Tensor) -> tuple[Tensor, Tensor]:
        """beta, alpha (B, 1, 1) each, from both clouds."""
        tag_t = template.new_zeros(*template.shape[:2], 1)
        tag_s = source.new_ones(*source.shape[:2], 1)
        both = torch.cat([torch.cat([template, tag_t], -1), torch.cat([source, tag_s], -1)], 1)
        beta, alpha = self.annealing_head(self.annealing_net(both).amax(1)).unbind(-1)
        return beta[:, None, None], alpha[:, None, None]

    def _step(self, template: Tensor, source: Tensor, _: int, template_features: Tensor):
        feat_s = self.point_features(source)
        beta, alpha = self.annealing(template, source)
        distance = torch.cdist(feat_s, template_features).square()
        match = sinkhorn(-beta * (distance - alpha), self.sinkhorn_iterations)  # (B, M, N)
        row = match.sum(2)  # (B, M): mass of each source point matched
        column = match.sum(1)  # (B, N)
        target = match @ template / row[..., None].clamp_min(1e-6)
        rotation, translation = rigid_align(source, target, row)
        inlier_loss = -(row.mean() + column.mean())  # the paper's: discourages all-slack
        return make_transform(rotation, translation), column.clamp(0, 1), inlier_loss

    def forward(
        self, template: Tensor, source: Tensor, max_iterations: int = 5
    ) -> RegistrationSolution:
        """Register ``source`` (B, M, 3) to ``template`` (B, N, 3); see the module docs."""
        template_features = None

        def step(tpl: Tensor, src: Tensor, i: int):
            nonlocal template_features
            if template_features is None:  # the template does not move: embed it once
                template_features = self.point_features(tpl)
            return self._step(tpl, src, i, template_features)

        return centred_registration(template, source, step, max_iterations)

"""PointNetLK (Aoki et al., CVPR 2019): Lucas-Kanade on PointNet features.

A PointNet encoder with a max pool maps a cloud to one feature vector phi(P).
Registration looks for the transform T with phi(T . source) = phi(template),
by inverse-compositional Lucas-Kanade on SE(3):

* the Jacobian J = d phi(exp(xi) . template) / d xi at xi = 0, (K, 6), is computed
  once per pair by finite differences (six perturbed copies of the template, step
  ``delta`` in each twist direction);
* each iteration measures the residual r = phi(T . source) - phi(template),
  solves xi = pinv(J) r (least squares), and updates T <- exp(-xi) T, because
  T . source ~= exp(xi) . template means exp(-xi) T . source ~= template.

Both clouds are first centred on their centroids (the template's over its valid
points only), so the iteration only has to find the remaining motion about the
template centroid; the returned transform includes the centring. Transform
convention: source -> template, ``template ~= source @ R.T + t``
(:mod:`masknet.geometry.se3`).

The encoder has no BatchNorm: a cloud's features must depend on that cloud only,
or the finite differences and residuals would mix batch statistics.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import torch
from torch import Tensor, nn

from masknet.geometry.align import centroid
from masknet.geometry.se3 import make_transform, se3_exp, transform_points
from masknet.models.pointnet import PointNetEncoder
from masknet.models.weights import SafetensorsWeights

__all__ = ["LKSolution", "PointNetLK"]


class LKSolution(NamedTuple):
    """Result of :meth:`PointNetLK.forward`.

    transform: (B, 4, 4) source -> template, in the dtype of the input clouds.
    residual: (B,) norm of the last feature residual phi(T . source) - phi(template).
    iterations: (B,) int64, updates applied.
    converged: (B,) bool, True where the update fell below the tolerance.
    """

    transform: Tensor
    residual: Tensor
    iterations: Tensor
    converged: Tensor

    @property
    def auxiliary_loss(self) -> Tensor:
        """() mean squared feature residual, PointNetLK's second training loss."""
        return self.residual.square().mean()


class PointNetLK(SafetensorsWeights, nn.Module):
    """PointNetLK: forward(template (B, N, 3), source (B, M, 3)) -> :class:`LKSolution`.

    Args:
        encoder_channels: the PointNet widths; the last is the feature size K
            (the paper's 1,024; the shipped model's card states its own).
        delta: finite-difference step for the Jacobian, in twist units
            (radians for the rotation part, cloud units for the translation part).
    """

    weights_prefix = "pointnetlk_"
    default_iterations = 10

    def __init__(
        self, encoder_channels: Sequence[int] = (64, 64, 64, 128, 1024), delta: float = 1e-2
    ):
        super().__init__()
        self.config = {"encoder_channels": list(encoder_channels), "delta": delta}
        self.encoder = PointNetEncoder(encoder_channels, batch_norm=False)
        self.delta = delta

    def features(self, points: Tensor, valid: Tensor | None = None) -> Tensor:
        """Max-pooled features (B, K) of clouds (B, N, 3), over ``valid`` (B, N) points only."""
        f = self.encoder(points)
        if valid is not None:
            f = f.masked_fill(~valid[..., None], float("-inf"))
        return f.amax(1)

    def jacobian(self, template: Tensor, valid: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """phi(template) (B, K) and its Jacobian (B, K, 6) by forward differences."""
        b, n, _ = template.shape
        steps = se3_exp(self.delta * torch.eye(6, dtype=template.dtype, device=template.device))
        perturbed = transform_points(steps[None], template[:, None])  # (B, 6, N, 3)
        clouds = torch.cat([template[:, None], perturbed], 1).reshape(b * 7, n, 3)
        mask = None if valid is None else valid.repeat_interleave(7, dim=0)
        f = self.features(clouds, mask).reshape(b, 7, -1)
        return f[:, 0], ((f[:, 1:] - f[:, :1]) / self.delta).transpose(1, 2)

    def forward(
        self,
        template: Tensor,
        source: Tensor,
        template_valid: Tensor | None = None,
        max_iterations: int = 10,
        tolerance: float = 1e-5,
    ) -> LKSolution:
        """Register ``source`` (B, M, 3) to ``template`` (B, N, 3).

        Args:
            template_valid: (B, N) bool; only these template points count (Mask-PointNetLK
                passes MaskNet's mask here). None uses every point.
            max_iterations: most LK updates (the paper's 10).
            tolerance: a pair stops once its update twist has norm below this
                (applied in eval mode only; training runs every iteration).
        """
        centre_t = centroid(template, template_valid)
        centre_s = centroid(source)
        tpl = template - centre_t[:, None]
        src = source - centre_s[:, None]
        f0, jac = self.jacobian(tpl, template_valid)
        jt = jac.transpose(1, 2)
        damping = 1e-6 * torch.eye(6, dtype=jac.dtype, device=jac.device)
        pinv = torch.linalg.solve(jt @ jac + damping, jt)  # (B, 6, K)

        b = template.shape[0]
        transform = torch.eye(4, dtype=template.dtype, device=template.device).repeat(b, 1, 1)
        done = torch.zeros(b, dtype=torch.bool, device=template.device)
        iterations = torch.zeros(b, dtype=torch.int64, device=template.device)
        residual = torch.zeros(b, dtype=template.dtype, device=template.device)
        for _ in range(max_iterations):
            r = self.features(transform_points(transform, src)) - f0
            residual = torch.where(done, residual, r.norm(dim=-1))
            xi = (pinv @ r[..., None])[..., 0]
            update = se3_exp(-xi) @ transform
            transform = torch.where(done[:, None, None], transform, update)
            iterations += (~done).long()
            if not self.training:
                done = done | (xi.norm(dim=-1) < tolerance)
                if bool(done.all()):
                    break
        eye = torch.eye(3, dtype=transform.dtype, device=transform.device).expand(b, 3, 3)
        full = make_transform(eye, centre_t) @ transform @ make_transform(eye, -centre_s)
        return LKSolution(full, residual, iterations, done)

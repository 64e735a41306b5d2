"""PointNet per-point encoder (Qi et al., CVPR 2017), channels-last."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from masknet.models.layers import linear_stack

__all__ = ["PointNetEncoder", "fold_batchnorm"]


class PointNetEncoder(nn.Module):
    """Shared per-point MLP: 3-64-64-64-128-1024 with BatchNorm and ReLU after every layer.

    The layers are ``nn.Linear`` applied to (B, N, C) tensors, the same maps as the
    paper's 1x1 convolutions on (B, C, N) but one GEMM each on CPU. With
    ``batch_norm=True`` linear layers carry no bias (the BatchNorm that follows
    makes it redundant); with ``batch_norm=False`` they do, and a cloud's features
    depend on that cloud alone, in training too (PointNetLK's finite differences
    need that).

    forward: points (B, N, 3) -> per-point features (B, N, channels[-1]).
    """

    def __init__(
        self,
        channels: Sequence[int] = (64, 64, 64, 128, 1024),
        in_channels: int = 3,
        batch_norm: bool = True,
    ):
        super().__init__()
        dims = [in_channels, *channels]
        self.linears = linear_stack(dims, bias=not batch_norm)
        self.norms = nn.ModuleList(
            nn.BatchNorm1d(c) if batch_norm else nn.Identity() for c in channels
        )

    @property
    def out_channels(self) -> int:
        return self.linears[-1].out_features

    def forward(self, points: Tensor) -> Tensor:
        b, n, _ = points.shape
        x = points.reshape(b * n, -1)
        for linear, norm in zip(self.linears, self.norms, strict=True):
            x = torch.relu(norm(linear(x)))
        return x.reshape(b, n, -1)


def fold_batchnorm(linear: nn.Linear, norm: nn.BatchNorm1d) -> tuple[Tensor, Tensor]:
    """Fold an eval-mode BatchNorm into the preceding linear layer.

    Returns (weight (out, in), bias (out,)) with
    ``norm(linear(x)) == x @ weight.T + bias`` using the running statistics.
    """
    scale = norm.weight / torch.sqrt(norm.running_var + norm.eps)
    bias = linear.bias if linear.bias is not None else torch.zeros_like(norm.running_mean)
    weight = linear.weight * scale[:, None]
    return weight.detach().clone(), (
        (bias - norm.running_mean) * scale + norm.bias
    ).detach().clone()

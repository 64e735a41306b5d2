"""MaskNet written the way the authors' library (learning3d) writes it, for comparison.

Conv1d layers on (B, C, N) tensors, the global source feature repeated and
concatenated to every template feature, BatchNorm applied unfolded, fp32. It
holds the same weights as :class:`~masknet.models.masknet.MaskNet` (Linear
weights become 1x1 convolution kernels) and computes the same function; it is
the "plain reference" against which the fast paths are timed.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from masknet.models.masknet import MaskNet, centre

__all__ = ["PaperMaskNet"]


class PaperMaskNet(nn.Module):
    """forward(template (B, N, 3), source (B, M, 3)) -> scores (B, N)."""

    def __init__(self, model: MaskNet):
        super().__init__()
        enc = []
        for linear, norm in zip(model.encoder.linears, model.encoder.norms, strict=True):
            conv = nn.Conv1d(linear.in_features, linear.out_features, 1, bias=False)
            conv.weight.data.copy_(linear.weight.data[..., None])
            bn = nn.BatchNorm1d(norm.num_features)
            bn.load_state_dict(norm.state_dict())
            enc += [conv, bn, nn.ReLU()]
        self.encoder = nn.Sequential(*enc)
        first = nn.Conv1d(2 * model.encoder.out_channels, model.head_template.out_features, 1)
        weight = torch.cat([model.head_template.weight, model.head_global.weight], dim=1)
        first.weight.data.copy_(weight[..., None])
        first.bias.data.copy_(model.head_template.bias.data)
        layers: list[nn.Module] = [first]
        for layer in model.head:
            conv = nn.Conv1d(layer.in_features, layer.out_features, 1)
            conv.weight.data.copy_(layer.weight.data[..., None])
            conv.bias.data.copy_(layer.bias.data)
            layers += [nn.ReLU(), conv]
        self.head = nn.Sequential(*layers, nn.Sigmoid())
        self.eval()

    def forward(self, template: Tensor, source: Tensor) -> Tensor:
        t = self.encoder(centre(template).transpose(1, 2))  # (B, C, N)
        g = self.encoder(centre(source).transpose(1, 2)).max(dim=2).values  # (B, C)
        joint = torch.cat([t, g[:, :, None].repeat(1, 1, t.shape[2])], dim=1)
        return self.head(joint).squeeze(1)

"""MaskNet's fused inference path (:meth:`masknet.models.masknet.MaskNet.fused`): the split
head, BatchNorm folded into the linear layers, optional bf16, and chunking over template
points for bounded memory on large clouds."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import Tensor, nn

from masknet.models.masknet import _DTYPES, Precision, centre_pair
from masknet.models.pointnet import fold_batchnorm

if TYPE_CHECKING:
    from masknet.models.masknet import MaskNet

__all__ = ["FusedMaskNet"]


class FusedMaskNet(nn.Module):
    """Inference-only MaskNet: split head, BatchNorm folded, optional bf16.

    forward(template (B, N, 3), source (B, M, 3), chunk_size) -> scores (B, N) float32.
    Matches :meth:`MaskNet.forward` in eval mode to ~1e-6 in fp32.
    """

    def __init__(
        self,
        encoder: list[tuple[Tensor, Tensor]],
        head_template: tuple[Tensor, Tensor],
        head_global: Tensor,
        head: list[tuple[Tensor, Tensor]],
        precision: Precision = "fp32",
        centring: str = "each",
    ):
        super().__init__()
        dtype = _DTYPES[precision]
        self.precision = precision
        self.centring = centring
        self.encoder = [(w.to(dtype), b.to(dtype)) for w, b in encoder]
        self.head_template = tuple(p.to(dtype) for p in head_template)
        self.head_global = head_global.to(dtype)
        self.head = [(w.to(dtype), b.to(dtype)) for w, b in head]

    @classmethod
    def from_masknet(cls, model: MaskNet, precision: Precision = "fp32") -> FusedMaskNet:
        enc = [
            fold_batchnorm(lin, bn)
            for lin, bn in zip(model.encoder.linears, model.encoder.norms, strict=True)
        ]
        ht = (
            model.head_template.weight.detach().clone(),
            model.head_template.bias.detach().clone(),
        )
        head = [
            (layer.weight.detach().clone(), layer.bias.detach().clone()) for layer in model.head
        ]
        global_weight = model.head_global.weight.detach().clone()
        return cls(enc, ht, global_weight, head, precision, model.centring)

    def _encode(self, x: Tensor) -> Tensor:
        for w, b in self.encoder:
            x = torch.relu(torch.addmm(b, x, w.t()))
        return x

    def _centred_template(self, template: Tensor) -> Tensor:
        """The template (B, N, 3) as the encoder sees it: centred on its own centroid
        (``centring="each"``), in the path's precision."""
        return (template.float() - template.float().mean(dim=1, keepdim=True)).to(
            self.head_global.dtype
        )

    @torch.inference_mode()
    def encode_template(self, template: Tensor, chunk_size: int | None = None) -> list[Tensor]:
        """The per-point template encoding, before the source's global feature is added:
        one (B * n, H) tensor per chunk of ``chunk_size`` template points (B, N, 3). It
        depends on the template alone where ``centring="each"``: computed once, it serves
        every source (:meth:`forward`'s ``template_features``), the same values as its own."""
        if self.centring != "each":
            raise ValueError("the template's encoding depends on the source: centring='source'")
        tpl = self._centred_template(template)
        step = tpl.shape[1] if chunk_size is None else chunk_size
        return [
            self._encode(tpl[:, start : start + step].reshape(-1, 3)) @ self.head_template[0].t()
            for start in range(0, tpl.shape[1], step)
        ]

    @torch.inference_mode()
    def forward(
        self,
        template: Tensor,
        source: Tensor,
        chunk_size: int | None = None,
        template_features: list[Tensor] | None = None,
    ) -> Tensor:
        """Scores (B, N) of template (B, N, 3) and source (B, M, 3); ``template_features``:
        :meth:`encode_template` of this template at this ``chunk_size``, computed before."""
        dtype = self.head_global.dtype
        b, n, _ = template.shape
        tpl, src = centre_pair(template.float(), source.float(), self.centring)
        tpl, src = tpl.to(dtype), src.to(dtype)
        step = n if chunk_size is None else chunk_size
        # The source's global feature, max-pooled chunk by chunk: the same maximum in
        # memory that does not grow with M.
        m_step = source.shape[1] if chunk_size is None else chunk_size
        g = torch.stack(
            [
                self._encode(src[:, i : i + m_step].reshape(-1, 3))
                .reshape(b, -1, self.head_global.shape[1])
                .amax(1)
                for i in range(0, source.shape[1], m_step)
            ]
        ).amax(0)
        g = g @ self.head_global.t() + self.head_template[1]  # (B, H): once per cloud
        out = []
        for index, start in enumerate(range(0, n, step)):
            part = tpl[:, start : start + step]
            if template_features is None:
                x = self._encode(part.reshape(-1, 3)) @ self.head_template[0].t()
            else:
                x = template_features[index]
            x = x.reshape(b, part.shape[1], -1) + g[:, None, :]
            x = x.reshape(-1, x.shape[-1])
            for w, bias in self.head:
                x = torch.addmm(bias, torch.relu(x), w.t())
            out.append(torch.sigmoid(x.float()).reshape(b, part.shape[1]))
        return torch.cat(out, dim=1)

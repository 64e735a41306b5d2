"""MaskNet (Sarode, Dhagat et al., 3DV 2020): which template points does the source see?

Architecture (the paper's):

* a shared PointNet encoder 3-64-64-64-128-1024 (BatchNorm, ReLU) on both clouds;
* the source features max-pooled into one global vector g (1024);
* [template feature_i ; g] (2048 channels) through a head 1024-512-256-128-1 with
  ReLU, and a sigmoid: one inlier score in [0, 1] per template point.

**Centring.** Before the network, each cloud is centred on its own centroid
(template on the template's, source on the source's). This removes most of the
translation the network would otherwise have to learn; it is part of the model,
applied by every forward path. For clouds that are already aligned (denoising: a
noisy scan scored against its registered template) their relative position is
information: ``MaskNet(centring="source")`` centres both on the source's centroid.

**Three forward paths, one function.**

* :meth:`MaskNet.forward_reference` is the paper's formulation: concatenate g to
  every template feature, then the first head layer on 2048 channels.
* :meth:`MaskNet.forward` splits that first layer, ``W [a_i; g] = W_a a_i + W_g g``,
  so the global half is computed once per cloud. Same function, used in training.
* :class:`FusedMaskNet` (via :meth:`MaskNet.fused`) is inference only: the split
  head, BatchNorm folded into the linear layers, optional bf16, and chunking over
  template points for bounded memory on large clouds.

**Selecting inliers.** :func:`select_mask` turns scores into a Boolean mask either
by top-k (k = number of source points by default, as the official code does) or
by a threshold epsilon (as the paper describes).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np
import torch
from torch import Tensor, nn

from masknet.geometry.clouds import MIN_POINTS
from masknet.models.layers import linear_stack
from masknet.models.mask_context import MaskContext
from masknet.models.mask_prediction import (
    PAIRS_PER_CALL,
    MaskPredictionMixin,
    Precision,
    ScoredMask,
    prepare_inputs,
    select_mask,
)
from masknet.models.pointnet import PointNetEncoder
from masknet.models.weights import SafetensorsWeights

__all__ = [
    "MaskNet",
    "FusedMaskNet",
    "ScoredMask",
    "select_mask",
    "predict_two_masks",
    "centre",
    "centre_pair",
    "PAIRS_PER_CALL",
    "MIN_POINTS",
]

_DTYPES = {"fp32": torch.float32, "bf16": torch.bfloat16}


def centre(points: Tensor) -> Tensor:
    """Subtract each cloud's centroid: (B, N, 3) -> (B, N, 3)."""
    return points - points.mean(dim=1, keepdim=True)


def centre_pair(template: Tensor, source: Tensor, centring: str) -> tuple[Tensor, Tensor]:
    """Both clouds centred: each on its own centroid (``"each"``), or both on the
    source's (``"source"``, for aligned clouds). (B, N, 3), (B, M, 3) in and out."""
    if centring == "each":
        return centre(template), centre(source)
    offset = source.mean(dim=1, keepdim=True)
    return template - offset, source - offset


@torch.inference_mode()
def predict_two_masks(
    model: nn.Module,
    template: np.ndarray,
    source: np.ndarray,
    precision: str,
    normalize: bool,
    pairs_per_call: int = PAIRS_PER_CALL,
) -> tuple[np.ndarray, np.ndarray]:
    """Scores of a network whose forward gives (template scores, source scores): numpy
    template (N, 3) or (B, N, 3) and source (M, 3) or (B, M, 3) -> ((N,) or (B, N),
    (M,) or (B, M)), float32, run ``pairs_per_call`` pairs at a time in eval mode."""
    device = next(model.parameters()).device
    t, s, single, precision = prepare_inputs(template, source, normalize, precision, device)
    was_training = model.training
    model.eval()
    outs_t, outs_s = [], []
    step = max(1, pairs_per_call)
    with torch.autocast(device.type, dtype=torch.bfloat16, enabled=precision == "bf16"):
        for i in range(0, t.shape[0], step):
            st, ss = model(t[i : i + step].to(device), s[i : i + step].to(device))
            outs_t.append(st.float().cpu())
            outs_s.append(ss.float().cpu())
    model.train(was_training)
    st, ss = torch.cat(outs_t).numpy(), torch.cat(outs_s).numpy()
    return (st[0], ss[0]) if single else (st, ss)


class MaskNet(MaskPredictionMixin, SafetensorsWeights, nn.Module):
    """The MaskNet network.

    Weights: :meth:`save`, :meth:`from_file` and :meth:`pretrained` (names
    ``"modelnet40"``, all 40 categories, and ``"modelnet40_seen20"``, the first 20)
    come from :class:`masknet.models.weights.SafetensorsWeights`.

    forward(template (B, N, 3), source (B, M, 3)) -> scores (B, N) in [0, 1].
    """

    weights_prefix = "masknet_"

    def __init__(
        self,
        encoder_channels: Sequence[int] = (64, 64, 64, 128, 1024),
        head_channels: Sequence[int] = (1024, 512, 256, 128),
        centring: Literal["each", "source"] = "each",
        context: int = 0,
    ):
        super().__init__()
        if centring not in ("each", "source"):
            raise ValueError(f"centring must be 'each' or 'source', got {centring!r}")
        self.config = {
            "encoder_channels": list(encoder_channels),
            "head_channels": list(head_channels),
        }
        if centring != "each":  # only then: the configs of earlier files stay as they were
            self.config["centring"] = centring
        if context and (isinstance(context, bool) or int(context) != context or context < 1):
            raise ValueError(f"context must be a number of neighbours >= 1, got {context!r}")
        if context:  # only then, as centring: earlier files' configs stay as they were
            self.config["context"] = int(context)
        self.centring = centring
        self.encoder = PointNetEncoder(encoder_channels)
        feat = self.encoder.out_channels
        # Beyond the paper: a residual correction from each template point's neighbourhood
        # and the source's points (masknet.models.mask_context); off (None) by default.
        self.context = MaskContext(feat, k=int(context)) if context else None
        # The first head layer on [template feature; global source feature], split in two.
        self.head_template = nn.Linear(feat, head_channels[0])
        self.head_global = nn.Linear(feat, head_channels[0], bias=False)
        self.head = linear_stack([*head_channels, 1])
        self._fused_cache: dict = {}

    # ------------------------------------------------------------------ forward paths

    def _head_tail(self, x: Tensor) -> Tensor:
        for layer in self.head:
            x = layer(torch.relu(x))
        return x.squeeze(-1)

    def forward(self, template: Tensor, source: Tensor, logits: bool = False) -> Tensor:
        """Split-head forward: (B, N, 3), (B, M, 3) -> scores (B, N) in [0, 1].

        ``logits=True`` returns the values before the sigmoid, for losses on logits (BCE),
        where a saturated sigmoid still gets a gradient.
        """
        template, source = centre_pair(template, source, self.centring)
        source_features = self.encoder(source)
        template_features = self.encoder(template)
        g = self.head_global(source_features.amax(dim=1))
        x = self._head_tail(self.head_template(template_features) + g[:, None, :])
        if self.context is not None:
            x = self.context(template, template_features, source_features, x)
        return x if logits else torch.sigmoid(x)

    def forward_reference(self, template: Tensor, source: Tensor) -> Tensor:
        """The paper's concatenation formulation; the same function as :meth:`forward`
        (without the context head, which is not the paper's)."""
        if self.context is not None:
            raise ValueError("forward_reference is the paper's network; this one has context")
        template, source = centre_pair(template, source, self.centring)
        g = self.encoder(source).amax(dim=1)
        t = self.encoder(template)
        joint = torch.cat([t, g[:, None, :].expand(-1, t.shape[1], -1)], dim=-1)
        weight = torch.cat([self.head_template.weight, self.head_global.weight], dim=1)
        return torch.sigmoid(
            self._head_tail(nn.functional.linear(joint, weight, self.head_template.bias))
        )

    # ------------------------------------------------------------------ fast inference
    def scorer(self, precision: Precision = "fp32"):
        """The inference path: ``scorer(precision)(template (B, N, 3), source (B, M, 3),
        chunk_size) -> scores (B, N)``. The fused path for the paper's network; with
        context, :meth:`forward` in eval mode (chunking does not apply)."""
        if self.context is None:
            return self.fused(precision)
        return self.forward_scorer(precision)

    def fused(self, precision: Precision = "fp32") -> FusedMaskNet:
        """The inference path for the current weights (cached until a weight changes)."""
        if self.context is not None:
            raise ValueError("the fused path is the paper's network; this one has context")
        tensors = [*self.parameters(), *self.buffers()]
        key = (precision, *((id(t), t._version, t.device) for t in tensors))
        if self._fused_cache.get("key") != key:
            self._fused_cache = {"key": key, "model": FusedMaskNet.from_masknet(self, precision)}
        return self._fused_cache["model"]


# The fused inference path lives in its own module; it is part of this one's interface.
from masknet.models.fused import FusedMaskNet  # noqa: E402

"""CrossMaskNet: MaskNet's job with local geometry and attention between the two clouds.

The paper's MaskNet scores a template point from its own PointNet feature (a function of
its coordinates alone) and one max-pooled vector of the source. Its mistakes sit where
that cannot decide: on the edge of the seen region, and wherever the source's global
shape says little about which side was cut (RESULTS, "Where Mask-PointNetLK's error
comes from"). CrossMaskNet gives each point what a point-wise head cannot see:

1. **local geometry** on each cloud: EdgeConv layers (DGCNN, Wang et al. 2019) over
   each point's ``k`` nearest points in space (a static graph: one 3-D KD-tree search
   per cloud), so a point's feature describes the surface around it;
2. **the other cloud**: ``layers`` steps of attention (:class:`~masknet.models.layers.
   CrossAttention`: self-attention on each cloud, then each cloud's points attend to the
   other's, as in DCP and Predator's overlap attention), so a template point's feature
   says whether some source point looks like it, and where;
3. a head on [template point feature; max-pooled source feature] -> one logit per
   template point, as the paper's head.

Inputs are centred as MaskNet's (each cloud on its own centroid); clouds are scaled by
the template's radius in :meth:`predict`, as for MaskNet.

``descriptors="fpfh"`` adds rotation-invariant inputs to the coordinates: each point's FPFH
descriptor and its distance to the nearest descriptor of the other cloud
(:mod:`masknet.models.descriptors`: Open3D's, or the same by numpy), computed in
:meth:`forward` from the clouds themselves, so training and every prediction method get
them with nothing else to pass. A 45-degree turn of the source hides from coordinates
what such descriptors still show.

forward(template (B, N, 3), source (B, M, 3), logits=False) -> scores (B, N) in [0, 1].
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from masknet.errors import MaskNetError
from masknet.models.descriptors import DESCRIPTOR_CHANNELS, pair_descriptors
from masknet.models.layers import EdgeConvEncoder, linear_stack, mlp
from masknet.models.mask_prediction import MaskPredictionMixin, Precision
from masknet.models.masknet import centre_pair
from masknet.models.weights import SafetensorsWeights

__all__ = ["CrossMaskNet"]


class AttentionStep(nn.Module):
    """One step of attention from a cloud's points to the other cloud's: pre-norm
    multi-head attention whose keys and values are at most ``keys`` of the other cloud's
    points (evenly strided: which side of the object a point is on is a regional
    question, and 256 keys cost a quarter of 1,024), then a feed-forward layer; both
    residual.

    forward: queries (B, N, F), other (B, M, F) -> (B, N, F).
    """

    def __init__(self, features: int, heads: int, keys: int):
        super().__init__()
        self.keys = keys
        self.norm_query = nn.LayerNorm(features)
        self.norm_other = nn.LayerNorm(features)
        self.attention = nn.MultiheadAttention(features, heads, batch_first=True)
        self.feedforward = nn.Sequential(
            nn.LayerNorm(features),
            nn.Linear(features, 2 * features),
            nn.ReLU(),
            nn.Linear(2 * features, features),
        )

    def forward(self, queries: Tensor, other: Tensor) -> Tensor:
        stride = -(-other.shape[1] // self.keys)  # ceil: at most ``keys`` keys
        memory = self.norm_other(other[:, ::stride])
        attended, _ = self.attention(self.norm_query(queries), memory, memory, need_weights=False)
        x = queries + attended
        return x + self.feedforward(x)


class CrossMaskNet(MaskPredictionMixin, SafetensorsWeights, nn.Module):
    """A template mask from local geometry and cross-attention (see the module's docs).

    Args:
        channels: EdgeConv widths on each cloud.
        features: F, the per-point feature width after the EdgeConv layers.
        k: neighbours of each point's EdgeConv graph.
        layers: attention steps between the clouds.
        heads: attention heads.
        keys: at most this many points of the other cloud serve as keys in each step.
        head_channels: widths of the scoring head after [feature; source feature].
        descriptors: None (coordinates only) or ``"fpfh"``: per-point FPFH descriptors and
            descriptor-match distances beside the coordinates (see the module's docs).

    Weights: :meth:`save`, :meth:`from_file`, :meth:`pretrained` (shipped files
    ``resources/weights/crossmasknet_<name>.safetensors``). The prediction methods are
    MaskNet's (:class:`~masknet.models.mask_prediction.MaskPredictionMixin`).
    """

    weights_prefix = "crossmasknet_"

    def __init__(
        self,
        channels: Sequence[int] = (32, 32, 64),
        features: int = 64,
        k: int = 16,
        layers: int = 2,
        heads: int = 4,
        keys: int = 256,
        head_channels: Sequence[int] = (64, 32),
        descriptors: str | None = None,
    ):
        super().__init__()
        if k < 2 or layers < 0 or features % heads:
            raise ValueError(
                f"need k >= 2, layers >= 0 and features divisible by heads; got k={k}, "
                f"layers={layers}, features={features}, heads={heads}"
            )
        if descriptors is not None and descriptors not in DESCRIPTOR_CHANNELS:
            raise MaskNetError(
                f"descriptors must be None or one of {sorted(DESCRIPTOR_CHANNELS)}, "
                f"got {descriptors!r}"
            )
        self.descriptors = descriptors
        self.config = {
            "channels": list(channels),
            "features": features,
            "k": k,
            "layers": layers,
            "heads": heads,
            "keys": keys,
            "head_channels": list(head_channels),
        }
        if descriptors is not None:  # only then: earlier files' configs stay as they were
            self.config["descriptors"] = descriptors
        extra = DESCRIPTOR_CHANNELS[descriptors] if descriptors else 0
        self.encoder = EdgeConvEncoder(channels, features, k=k, dynamic=False, extra_channels=extra)
        # Per layer: template points attend to the source's, then source to template's.
        self.to_source = nn.ModuleList(AttentionStep(features, heads, keys) for _ in range(layers))
        self.to_template = nn.ModuleList(
            AttentionStep(features, heads, keys) for _ in range(layers)
        )
        self.head = linear_stack([2 * features, *head_channels, 1])

    def forward(self, template: Tensor, source: Tensor, logits: bool = False) -> Tensor:
        """(B, N, 3), (B, M, 3) -> scores (B, N) in [0, 1], or logits with ``logits=True``.

        With ``descriptors`` set, they are computed here from the clouds (on the CPU,
        without autograd)."""
        t_extra = s_extra = None
        if self.descriptors is not None:
            t_extra, s_extra = pair_descriptors(template, source, self.descriptors)
        template, source = centre_pair(template, source, "each")
        t, s = self.encoder(template, t_extra), self.encoder(source, s_extra)
        for to_source, to_template in zip(self.to_source, self.to_template, strict=True):
            t, s = to_source(t, s), to_template(s, t)
        pooled = s.amax(dim=1, keepdim=True).expand(-1, t.shape[1], -1)
        x = mlp(self.head, torch.cat([t, pooled], dim=-1)).squeeze(-1)
        return x if logits else torch.sigmoid(x)

    def auto_precision(self, device: torch.device) -> Precision:
        """fp32 on CPUs: at batch 1 (1,024 / 717 points, 2 threads) bf16 autocast runs this
        network's many small layers slower than fp32, even with AVX512-BF16 (20.9 ms against
        17.5 ms, ``scripts/mask_speed.py``); bf16 on GPUs."""
        return "fp32" if device.type == "cpu" else super().auto_precision(device)

    def scorer(self, precision: Precision = "fp32"):
        """The inference path, :meth:`forward` under ``precision``'s autocast
        (:meth:`~masknet.models.mask_prediction.MaskPredictionMixin.forward_scorer`)."""
        return self.forward_scorer(precision)

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

import warnings
from collections.abc import Sequence
from typing import Literal, NamedTuple

import numpy as np
import torch
from torch import Tensor, nn

from masknet.geometry.clouds import MIN_POINTS, as_cloud_batch, unit_radius
from masknet.models.layers import linear_stack
from masknet.models.mask_context import MaskContext
from masknet.models.pointnet import PointNetEncoder
from masknet.models.weights import SafetensorsWeights
from masknet.runtime import default_precision

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

Precision = Literal["fp32", "bf16"]
_DTYPES = {"fp32": torch.float32, "bf16": torch.bfloat16}

# Pairs per batched call when scoring or registering many pairs. On CPU, batches of a few
# pairs keep each layer's (B, N, C) activations in cache: MaskNet's bf16 path runs about
# 2x faster per pair at 8 than at 64, PointNetLK and PRNet 1.5-2.5x (2-core EPYC, 2 threads).
PAIRS_PER_CALL = 8


class ScoredMask(NamedTuple):
    """A template mask and the scores it was selected from, as
    :meth:`MaskNet.predict_mask_with_scores` returns them: mask (N,) or (B, N) bool, scores
    (N,) or (B, N) float32 in [0, 1]."""

    mask: np.ndarray
    scores: np.ndarray


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


def select_mask(
    scores: Tensor, k: int | Tensor | None = None, threshold: float | None = None
) -> Tensor:
    """Boolean inlier mask from scores (B, N) or (N,), same shape out.

    Exactly one rule applies: ``threshold`` keeps scores >= threshold (the paper's
    epsilon); otherwise top-``k`` keeps the k highest scores per row (k an int or a
    (B,) tensor; the official code uses k = number of source points).
    """
    if scores.dim() == 1:
        return select_mask(scores[None], k, threshold)[0]
    if threshold is not None:
        if k is not None:
            raise ValueError("give either k or threshold, not both")
        return scores >= threshold
    if k is None:
        raise ValueError("top-k selection needs k (e.g. the number of source points)")
    n = scores.shape[-1]
    ks = torch.as_tensor(k, device=scores.device).clamp(0, n).expand(scores.shape[0])
    ranks = scores.argsort(dim=-1, descending=True).argsort(dim=-1)
    return ranks < ks[:, None]


def select_template_mask(
    scores: Tensor, source: np.ndarray, k: int | None, threshold: float | None
) -> Tensor:
    """A template mask from its scores (B, N) or (N,) by the options of a network's
    ``predict_mask(s)``: top-k with k = M, the number of ``source`` points (the official
    code's rule), unless ``k`` or ``threshold`` is given (:func:`select_mask`)."""
    if threshold is None and k is None:
        k = np.shape(source)[-2]
    return select_mask(scores, k=k, threshold=threshold)


def prepare_inputs(
    template: np.ndarray,
    source: np.ndarray,
    normalize: bool,
    precision: str,
    device: torch.device,
) -> tuple[Tensor, Tensor, bool, str]:
    """Numpy clouds as a network's ``predict`` takes them: validated float32 batches
    (B, N, 3) and (B, M, 3), scaled by each template's radius when ``normalize``, whether
    the input was one pair, and ``precision`` with ``"auto"`` resolved for ``device``."""
    t, s, single = as_cloud_batch(template, source)
    if normalize:
        radius = unit_radius(t)[:, None, None]
        t, s = t / radius, s / radius
    if precision == "auto":
        precision = default_precision(device)
    return t, s, single, precision


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


class MaskNet(SafetensorsWeights, nn.Module):
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

        def scores(template: Tensor, source: Tensor, chunk_size: int | None = None) -> Tensor:
            was_training = self.training
            self.eval()
            try:
                with torch.autocast(
                    template.device.type, dtype=torch.bfloat16, enabled=precision == "bf16"
                ):
                    return torch.sigmoid(self(template, source, logits=True).float())
            finally:
                self.train(was_training)

        return scores

    def fused(self, precision: Precision = "fp32") -> FusedMaskNet:
        """The inference path for the current weights (cached until a weight changes)."""
        if self.context is not None:
            raise ValueError("the fused path is the paper's network; this one has context")
        tensors = [*self.parameters(), *self.buffers()]
        key = (precision, *((id(t), t._version, t.device) for t in tensors))
        if self._fused_cache.get("key") != key:
            self._fused_cache = {"key": key, "model": FusedMaskNet.from_masknet(self, precision)}
        return self._fused_cache["model"]

    @torch.inference_mode()
    def predict(
        self,
        template: np.ndarray,
        source: np.ndarray,
        precision: Precision | Literal["auto"] = "auto",
        chunk_size: int | None = 8192,
        normalize: bool = True,
        pairs_per_call: int = PAIRS_PER_CALL,
    ) -> np.ndarray:
        """Inlier scores for numpy clouds.

        Args:
            template: (N, 3) or (B, N, 3).
            source: (M, 3) or (B, M, 3).
            precision: ``"auto"`` (default: bf16 where the hardware runs it natively,
                CPUs with AVX512-BF16/AMX and GPUs; else fp32), ``"fp32"`` or
                ``"bf16"``. bf16 is about 3.5x faster than fp32 on such CPUs and keeps
                99.7% of the top-k mask (docs/RESULTS.md).
            chunk_size: template points processed at a time (bounds memory).
            normalize: scale each pair by its template's radius (about its
                bounding-box centre), as the ModelNet40 training shapes were, so
                clouds in any unit (mm, m) work. A no-op for unit-radius shapes.
            pairs_per_call: a batch is scored this many pairs at a time; the scores do
                not depend on it, only the speed (see :data:`PAIRS_PER_CALL`).

        Returns:
            scores (N,) or (B, N), float32 in [0, 1].
        """
        scores, single = self._scores(
            template, source, precision, chunk_size, normalize, pairs_per_call
        )
        out = scores.numpy()
        return out[0] if single else out

    def _scores(
        self,
        template: np.ndarray,
        source: np.ndarray,
        precision: Precision | Literal["auto"],
        chunk_size: int | None = 8192,
        normalize: bool = True,
        pairs_per_call: int = PAIRS_PER_CALL,
    ) -> tuple[Tensor, bool]:
        """:meth:`predict`'s scores as a CPU tensor (B, N), and whether one pair was given:
        the clouds enter torch in one conversion, and callers take out only what they need."""
        device = next(self.parameters()).device
        t, s, single, precision = prepare_inputs(template, source, normalize, precision, device)
        fused = self.scorer(precision)
        step = max(1, pairs_per_call)
        scores = torch.cat(
            [
                fused(t[i : i + step].to(device), s[i : i + step].to(device), chunk_size)
                .float()
                .cpu()
                for i in range(0, t.shape[0], step)
            ]
        )
        return scores, single

    def predict_mask(
        self,
        template: np.ndarray,
        source: np.ndarray,
        k: int | None = None,
        threshold: float | None = None,
        precision: Precision | Literal["auto"] = "auto",
        normalize: bool = True,
        return_scores: bool | None = None,
    ) -> np.ndarray:
        """Boolean inlier mask, (N,) or (B, N), for template (N, 3) or (B, N, 3) and
        source (M, 3) or (B, M, 3).

        By default top-k with k = M, the number of source points. Pass ``k`` for
        another top-k, or ``threshold`` for the paper's epsilon rule.
        :meth:`predict_mask_with_scores` gives the scores beside the mask.

        ``return_scores`` is deprecated (it changed the return type): use
        :meth:`predict_mask_with_scores`.
        """
        if return_scores is None:  # the mask alone leaves torch: one conversion
            mask, _, single = self._mask(template, source, k, threshold, precision, normalize)
            return mask.numpy()[0] if single else mask.numpy()
        scored = self.predict_mask_with_scores(
            template, source, k=k, threshold=threshold, precision=precision, normalize=normalize
        )
        if return_scores is not None:
            warnings.warn(
                "predict_mask(..., return_scores=...) is deprecated and will be removed in "
                "the next release; use predict_mask_with_scores(template, source), which "
                "returns (mask, scores)",
                DeprecationWarning,
                stacklevel=2,
            )
            if return_scores:
                return tuple(scored)
        return scored.mask

    def predict_mask_with_scores(
        self,
        template: np.ndarray,
        source: np.ndarray,
        *,
        k: int | None = None,
        threshold: float | None = None,
        precision: Precision | Literal["auto"] = "auto",
        normalize: bool = True,
    ) -> ScoredMask:
        """:meth:`predict_mask`'s mask and the scores it was selected from, from one
        forward pass: ``ScoredMask(mask, scores)``, the mask (N,) or (B, N) bool and the
        scores as :meth:`predict` gives them."""
        mask, scores, single = self._mask(template, source, k, threshold, precision, normalize)
        mask, scores = mask.numpy(), scores.numpy()
        return ScoredMask(mask[0], scores[0]) if single else ScoredMask(mask, scores)

    @torch.inference_mode()
    def _mask(
        self,
        template: np.ndarray,
        source: np.ndarray,
        k: int | None,
        threshold: float | None,
        precision: Precision | Literal["auto"],
        normalize: bool,
    ) -> tuple[Tensor, Tensor, bool]:
        """The mask (B, N) and scores (B, N) as tensors, and whether one pair was given."""
        scores, single = self._scores(template, source, precision, normalize=normalize)
        return select_template_mask(scores, source, k, threshold), scores, single

    def predict_masks(
        self,
        template: np.ndarray,
        source: np.ndarray,
        *,
        k: int | None = None,
        threshold: float | None = None,
        precision: Precision | Literal["auto"] = "auto",
        normalize: bool = True,
    ) -> tuple[np.ndarray, None]:
        """The mask protocol every mask network answers: ``(template mask, source mask)``.

        MaskNet masks the template only, so the source mask is None (every source point
        kept). The template mask is :meth:`predict_mask`'s: top-k with k = M, the number of
        source points, unless ``k`` or ``threshold`` is given, as
        :meth:`masknet.models.TwoSidedMaskNet.predict_masks` selects its template mask.
        """
        mask = self.predict_mask(
            template, source, k=k, threshold=threshold, precision=precision, normalize=normalize
        )
        return mask, None


# The fused inference path lives in its own module; it is part of this one's interface.
from masknet.models.fused import FusedMaskNet  # noqa: E402

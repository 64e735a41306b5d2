"""What every template-mask network answers: scores, masks, and the mask protocol.

A network mixes in :class:`MaskPredictionMixin` and provides ``scorer(precision)``, a callable
``(template (B, N, 3), source (B, M, 3), chunk_size) -> scores (B, N)`` in [0, 1]; the
mixin turns numpy clouds into validated, radius-scaled batches, runs the scorer a few
pairs at a time and selects masks (top-k with k = M, or a threshold).
"""

from __future__ import annotations

import warnings
from typing import Any, Literal, NamedTuple

import numpy as np
import torch
from torch import Tensor

from masknet.geometry.clouds import as_cloud_batch, unit_radius
from masknet.runtime import default_precision

__all__ = [
    "PAIRS_PER_CALL",
    "MaskPredictionMixin",
    "Precision",
    "ScoredMask",
    "prepare_inputs",
    "select_mask",
    "select_template_mask",
]

Precision = Literal["fp32", "bf16"]

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


class MaskPredictionMixin:
    """Mixin of :class:`masknet.models.MaskNet` and :class:`masknet.models.CrossMaskNet`:
    :meth:`predict`, :meth:`predict_mask`, :meth:`predict_mask_with_scores` and
    :meth:`predict_masks`, from the network's ``scorer``."""

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
        if precision == "auto":
            precision = self.auto_precision(device)
        t, s, single, precision = prepare_inputs(template, source, normalize, precision, device)
        fused = self.scorer(precision)
        encoded = _template_encoding(fused, template, t, device, chunk_size, normalize)
        if encoded is not None:  # one pair, its template's encoding prepared
            scores = fused(t.to(device), s.to(device), chunk_size, encoded).float().cpu()
            return scores, single
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

    def auto_precision(self, device: torch.device) -> Precision:
        """What ``precision="auto"`` runs on ``device``: bf16 where the hardware runs it
        natively (:func:`masknet.runtime.default_precision`), else fp32. A network whose
        bf16 path is slower where it runs overrides this."""
        return default_precision(device)

    def forward_scorer(self, precision: Precision = "fp32"):
        """A ``scorer`` from the network's own forward: ``(template (B, N, 3), source
        (B, M, 3), chunk_size) -> scores (B, N)``, in eval mode under ``precision``'s
        autocast (``chunk_size`` does not apply), without autograd (as the fused path: a
        graph kept with each batch's scores grew an evaluation of 1,000 pairs past 20 GB).
        For networks without a fused path."""

        def scores(template: Tensor, source: Tensor, chunk_size: int | None = None) -> Tensor:
            was_training = self.training
            self.eval()
            try:
                with (
                    torch.inference_mode(),
                    torch.autocast(
                        template.device.type, dtype=torch.bfloat16, enabled=precision == "bf16"
                    ),
                ):
                    return torch.sigmoid(self(template, source, logits=True).float())
            finally:
                self.train(was_training)

        return scores


def _template_encoding(
    fused: Any,
    template: np.ndarray,
    t: Tensor,
    device: torch.device,
    chunk_size: int | None,
    normalize: bool,
) -> list[Tensor] | None:
    """The fused path's per-point encoding of one template (``t``: (1, N, 3), the network's
    input made from the numpy ``template``), from the active prepared template's cache
    (:mod:`masknet.geometry.prepared_template`) where it handed ``template`` out; None
    where there is none to use (a batch, another scorer, a source-centred network)."""
    from masknet.geometry.prepared_template import active, template_view

    encode = getattr(fused, "encode_template", None)
    if active() is None or encode is None or t.shape[0] != 1 or fused.centring != "each":
        return None
    key = ("network encoding", fused, chunk_size, normalize, str(device))
    return template_view(template, key, lambda: encode(t.to(device), chunk_size))

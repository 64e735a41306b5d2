"""Refinement masks: both inlier masks of a pair that registration has already brought close.

The paper's MaskNet centres each cloud on its own centroid, so it never sees where the
source lies relative to the template: rounds >= 2 of the iterative loop learn nothing
from the pose found. This network takes the pair **in one frame**, the source moved by
the current estimate, and predicts

* the template points that the source covers (``template_mask``), and
* the source points that lie on the template's object (``source_mask``: noise points,
  outliers and clutter are rejected).

Every point is described by two local contexts, each max-pooled over ``k`` neighbours
through a small shared MLP:

1. **its own cloud**: offsets to its k nearest neighbours in units of that cloud's
   median k-th-neighbour distance, with their lengths (density-free shape);
2. **the other cloud**: offsets to its k nearest points of the other cloud, in units of
   the other cloud's spacing, their lengths in that unit and in template radii, and
   the ratio of the two clouds' spacings. The nearest-neighbour distance, the cue of the
   plain nearest-neighbour rule, is one of these inputs; the network learns when to
   trust it (noise, different densities, outliers that happen to lie near the surface,
   a residual rotation that moves far points more).

A point MLP, a max-pool per cloud, and one head per role (the template's points and
the source's) give the logits. With ``context`` channels (v1.1 on), each point's head
also sees its own neighbourhood's features (their max and mean over its k nearest points
in its cloud): whether a point lies on the seen surface is a property of a patch, not of
one point, and the edge of a view or a hidden patch is decided by the points around it.
All offsets are taken in the shared frame, scaled by the template's radius, so nothing
depends on the unit or on where the pair sits.

forward(template (B, N, 3), source (B, M, 3)) -> (template scores (B, N), source scores
(B, M)) in [0, 1] (logits with ``logits=True``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np
import torch
from torch import Tensor, nn

from masknet.geometry.clouds import MIN_POINTS
from masknet.geometry.knn import knn_points
from masknet.models.layers import gather_points, linear_stack, mlp, mlp_pool
from masknet.models.masknet import PAIRS_PER_CALL, predict_two_masks, select_mask
from masknet.models.weights import SafetensorsWeights

__all__ = ["RefineMaskNet", "cross_offsets", "kth_spacing", "masks_from_scores"]

CONTEXT_SQUEEZE = 64  # channels of each point's features that its neighbours pool


def kth_spacing(points: Tensor, k: int) -> tuple[Tensor, Tensor]:
    """Each cloud's median distance to its k-th nearest other point, and the neighbours.

    points (B, P, 3) -> (spacing (B,), neighbour indices (B, P, k), the point itself
    excluded; k clamped to P - 1).
    """
    k = max(1, min(k, points.shape[1] - 1))
    with torch.no_grad():
        found = knn_points(points.float(), points.float(), k + 1)
    d = found.dists[:, :, -1].clamp_min(0).sqrt()
    return d.median(dim=1).values.clamp_min(1e-9), found.idx[:, :, 1:]


def cross_offsets(
    query: Tensor, reference: Tensor, k: int, reference_spacing: Tensor, query_spacing: Tensor
) -> Tensor:
    """Offsets from each query point to its k nearest reference points.

    query (B, P, 3), reference (B, R, 3), in template radii; spacings (B,) each.
    Returns (B, P, k, 6): offset / reference spacing (3), its length in that unit,
    its length in template radii, and log(reference spacing / query spacing).
    """
    k = max(1, min(k, reference.shape[1]))
    with torch.no_grad():
        idx = knn_points(query.float(), reference.float(), k).idx
    offsets = gather_points(reference, idx) - query[:, :, None, :]
    length = offsets.norm(dim=-1, keepdim=True)
    unit = reference_spacing[:, None, None, None]
    ratio = torch.log(reference_spacing / query_spacing)[:, None, None, None].expand_as(length)
    return torch.cat([offsets / unit, length / unit, length, ratio], dim=-1)


class RefineMaskNet(SafetensorsWeights, nn.Module):
    """Template and source masks of a pair in one frame (see the module docstring).

    Weights: :meth:`save`, :meth:`from_file`, :meth:`pretrained` (shipped files are
    ``refinemask_<name>.safetensors``).
    """

    weights_prefix = "refinemask_"

    def __init__(
        self,
        k: int = 12,
        local_channels: Sequence[int] = (32, 64),
        point_channels: Sequence[int] = (128, 256),
        head_channels: Sequence[int] = (128, 64),
        context: int = 0,
    ):
        super().__init__()
        self.config = {
            "k": k,
            "local_channels": list(local_channels),
            "point_channels": list(point_channels),
            "head_channels": list(head_channels),
        }
        if context:  # absent from v1.0 files, which rebuild without it
            self.config["context"] = context
        self.k = k
        self.own = linear_stack([4, *local_channels])
        self.cross = linear_stack([6, *local_channels])
        self.point = linear_stack([2 * local_channels[-1], *point_channels])
        feat = point_channels[-1]
        # The neighbourhood's features: squeezed per point, pooled over its k neighbours.
        self.context = (
            nn.ModuleList(
                [nn.Linear(feat, CONTEXT_SQUEEZE), nn.Linear(3 * CONTEXT_SQUEEZE, context)]
            )
            if context
            else None
        )
        self.template_head = linear_stack([3 * feat + context, *head_channels, 1])
        self.source_head = linear_stack([3 * feat + context, *head_channels, 1])

    @classmethod
    def pretrained(
        cls, name: str = "scans", map_location: str | torch.device = "cpu"
    ) -> RefineMaskNet:
        """Shipped weights (default ``"scans"``; its card is ``refinemask_scans.md``)."""
        return super().pretrained(name, map_location)

    def with_context(self, context: int) -> RefineMaskNet:
        """A copy with ``context`` channels that predicts exactly what this one does: every
        weight copied, the heads' weights on the new channels zero (a start to fine-tune)."""
        wider = RefineMaskNet(**{**self.config, "context": context})
        state = wider.state_dict()
        for name, value in self.state_dict().items():
            if state[name].shape == value.shape:
                state[name] = value.clone()
            else:  # a head's first layer: the old inputs first, the context's after
                state[name] = torch.zeros_like(state[name])
                state[name][:, : value.shape[1]] = value
        wider.load_state_dict(state)
        return wider

    def _features(
        self, points: Tensor, other: Tensor, own: tuple[Tensor, Tensor], other_spacing: Tensor
    ) -> Tensor:
        """Per-point features (B, P, C) of ``points`` against ``other``."""
        spacing, idx = own
        offsets = gather_points(points, idx) - points[:, :, None, :]
        length = offsets.norm(dim=-1, keepdim=True)
        unit = spacing[:, None, None, None]
        local = mlp_pool(self.own, torch.cat([offsets, length], dim=-1) / unit)
        cross = mlp_pool(self.cross, cross_offsets(points, other, self.k, other_spacing, spacing))
        x = torch.cat([local, cross], dim=-1)
        for layer in self.point:
            x = torch.relu(layer(x))
        return x

    def _context(self, x: Tensor, idx: Tensor) -> Tensor | None:
        """(B, P, context) from features x (B, P, C) and each point's own neighbours idx
        (B, P, k): squeezed features, their max and mean over the neighbours, mixed."""
        if self.context is None:
            return None
        squeeze, spread = self.context
        z = torch.relu(squeeze(x))
        around = gather_points(z, idx)  # (B, P, k, CONTEXT_SQUEEZE)
        return torch.relu(spread(torch.cat([z, around.amax(2), around.mean(2)], dim=-1)))

    @staticmethod
    def _head(
        layers: nn.ModuleList, x: Tensor, g_own: Tensor, g_other: Tensor, around: Tensor | None
    ) -> Tensor:
        b, p, _ = x.shape
        parts = [x, g_own[:, None].expand(b, p, -1), g_other[:, None].expand(b, p, -1)]
        return mlp(layers, torch.cat(parts if around is None else [*parts, around], -1)).squeeze(-1)

    def forward(
        self, template: Tensor, source: Tensor, logits: bool = False
    ) -> tuple[Tensor, Tensor]:
        """template (B, N, 3) and source (B, M, 3) in one frame, about unit template radius
        -> template scores (B, N), source scores (B, M)."""
        offset = template.mean(dim=1, keepdim=True)  # one shared frame: relative position kept
        template, source = template - offset, source - offset
        own_t, own_s = kth_spacing(template, self.k), kth_spacing(source, self.k)
        f_t = self._features(template, source, own_t, own_s[0])
        f_s = self._features(source, template, own_s, own_t[0])
        g_t, g_s = f_t.amax(dim=1), f_s.amax(dim=1)
        c_t, c_s = self._context(f_t, own_t[1]), self._context(f_s, own_s[1])
        t_logits = self._head(self.template_head, f_t, g_t, g_s, c_t)
        s_logits = self._head(self.source_head, f_s, g_s, g_t, c_s)
        if logits:
            return t_logits, s_logits
        return torch.sigmoid(t_logits), torch.sigmoid(s_logits)

    # ------------------------------------------------------------------ numpy inference
    @torch.inference_mode()
    def predict(
        self,
        template: np.ndarray,
        source: np.ndarray,
        precision: Literal["auto", "fp32", "bf16"] = "fp32",
        normalize: bool = True,
        pairs_per_call: int = PAIRS_PER_CALL,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Scores for numpy clouds in one frame: template (N, 3) or (B, N, 3), source (M, 3)
        or (B, M, 3) -> (template scores (N,) or (B, N), source scores (M,) or (B, M)),
        float32 in [0, 1]. ``normalize`` scales each pair by its template's radius."""
        return predict_two_masks(self, template, source, precision, normalize, pairs_per_call)

    def predict_masks(
        self,
        template: np.ndarray,
        source: np.ndarray,
        *,
        k: int | None = None,
        threshold: float | None = None,
        source_threshold: float = 0.5,
        precision: Literal["auto", "fp32", "bf16"] = "fp32",
        normalize: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Boolean masks (template (N,) or (B, N), source (M,) or (B, M)) for clouds in one
        frame. Source points are kept at score >= ``source_threshold``. The template mask
        is the top ``k`` scores, by default as many as there are kept source points
        (MaskNet's top-k rule), or the scores >= ``threshold`` when that is given."""
        t_scores, s_scores = self.predict(template, source, precision, normalize)
        return masks_from_scores(t_scores, s_scores, k, threshold, source_threshold)


def masks_from_scores(
    template_scores: np.ndarray,
    source_scores: np.ndarray,
    k: int | None = None,
    threshold: float | None = None,
    source_threshold: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`RefineMaskNet.predict_masks` from scores already predicted: template (N,) or
    (B, N) and source (M,) or (B, M) in [0, 1] -> the two boolean masks, as there."""
    source_mask = source_scores >= source_threshold
    # As the rule does: a pair with under 3 kept points keeps them all.
    few = np.atleast_2d(source_mask).sum(-1) < MIN_POINTS
    if few.any():
        source_mask = np.where(few[:, None], True, np.atleast_2d(source_mask))
        source_mask = source_mask.reshape(source_scores.shape)
    if k is None and threshold is None:
        k = torch.from_numpy(np.atleast_1d(source_mask.sum(-1)).clip(3))
    scores = torch.from_numpy(template_scores)
    template_mask = select_mask(scores, k=k, threshold=threshold).numpy()
    return template_mask, source_mask

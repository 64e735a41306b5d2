"""Two-sided MaskNet: one pass predicts which template points the source sees *and*
which source points belong to the template's object.

The paper's MaskNet (:class:`~masknet.models.masknet.MaskNet`) masks the template only,
so outliers and clutter in the source reach the registration untouched, and they
pollute the one global source feature the template mask is computed from. Following
the idea of MaskNet++ (the two clouds exchange global features), this network adds a
source branch and gates the template branch with it:

1. The shared PointNet encoder gives per-point features of both clouds (the paper's
   encoder, 1024 channels).
2. **Source branch.** Each source point is scored from three parts, summed in the
   first layer of a small head (256-128-1): its own encoder feature; a local context,
   max-pooled over its ``k`` nearest source neighbours from the offsets
   ``(x_j - x_i) / s`` and their lengths, where ``s`` is the source's median distance
   to its ``k``-th neighbour (so isolated outliers stand out at any density); and the
   template's global feature (max-pool of the template's features), which says what
   object to look for.
3. **Template branch.** The paper's head, on the template's features and the source's
   global feature, where that global feature is a max-pool over the *kept* source
   points only (score >= 0.5): rejected points no longer pollute it. With every source
   point kept it is exactly the paper's MaskNet.

Training (:class:`~masknet.training.two_sided_task.TwoSidedTask`) starts the
encoder and the template branch from shipped MaskNet weights and freezes them
(``frozen=True``), so on clean pairs the template mask equals the paper network's, and
only the source branch learns.

forward(template (B, N, 3), source (B, M, 3)) -> (template scores (B, N), source scores
(B, M)), both in [0, 1] (logits with ``logits=True``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np
import torch
from torch import Tensor, nn

from masknet.geometry.knn import knn_points
from masknet.models.layers import gather_points, linear_stack, mlp_pool
from masknet.models.mask_prediction import PAIRS_PER_CALL, select_template_mask
from masknet.models.masknet import MaskNet, centre_pair, predict_two_masks
from masknet.models.weights import SafetensorsWeights

__all__ = ["TwoSidedMaskNet", "local_offsets"]


def local_offsets(points: Tensor, k: int) -> Tensor:
    """Offsets to each point's k nearest neighbours, in units of the cloud's median
    k-th-neighbour distance, with their lengths: (B, M, 3) -> (B, M, k, 4).

    The point itself is excluded; k is clamped to M - 1.
    """
    k = max(1, min(k, points.shape[1] - 1))
    with torch.no_grad():
        idx = knn_points(points.float(), points.float(), k + 1).idx[:, :, 1:]  # (B, M, k)
    offsets = gather_points(points, idx) - points[:, :, None, :]
    length = offsets.norm(dim=-1, keepdim=True)
    scale = length[:, :, -1, 0].median(dim=1).values.clamp_min(1e-9)[:, None, None, None]
    return torch.cat([offsets, length], dim=-1) / scale


class TwoSidedMaskNet(SafetensorsWeights, nn.Module):
    """Template and source inlier masks in one pass (see the module docstring).

    Weights: :meth:`save`, :meth:`from_file`, :meth:`pretrained` (shipped files are
    ``masknet2_<name>.safetensors``) and :meth:`from_masknet` (start from a paper
    MaskNet's weights).
    """

    weights_prefix = "masknet2_"

    def __init__(
        self,
        encoder_channels: Sequence[int] = (64, 64, 64, 128, 1024),
        head_channels: Sequence[int] = (1024, 512, 256, 128),
        local_channels: Sequence[int] = (64, 128),
        source_channels: Sequence[int] = (256, 128),
        k: int = 16,
        frozen: bool = True,
    ):
        super().__init__()
        self.config = {
            "encoder_channels": list(encoder_channels),
            "head_channels": list(head_channels),
            "local_channels": list(local_channels),
            "source_channels": list(source_channels),
            "k": k,
            "frozen": frozen,
        }
        self.k = k
        self.frozen = frozen
        # The paper's network: the encoder and the template branch.
        self.masknet = MaskNet(encoder_channels, head_channels)
        feat = self.masknet.encoder.out_channels
        self.local = linear_stack([4, *local_channels])
        hidden = source_channels[0]
        self.source_point = nn.Linear(feat, hidden)
        self.source_local = nn.Linear(local_channels[-1], hidden, bias=False)
        self.source_global = nn.Linear(feat, hidden, bias=False)
        self.source_head = linear_stack([*source_channels, 1])
        if frozen:
            self.masknet.requires_grad_(False)

    @classmethod
    def pretrained(
        cls, name: str = "scans", map_location: str | torch.device = "cpu"
    ) -> TwoSidedMaskNet:
        """Shipped weights (default ``"scans"``: ModelNet40 and real scans, with outliers
        and clutter; its card is ``masknet2_scans.md``)."""
        return super().pretrained(name, map_location)

    @classmethod
    def from_masknet(cls, masknet: MaskNet, **kwargs) -> TwoSidedMaskNet:
        """A two-sided network whose encoder and template branch are ``masknet``'s."""
        model = cls(
            encoder_channels=masknet.config["encoder_channels"],
            head_channels=masknet.config["head_channels"],
            **kwargs,
        )
        model.masknet.load_state_dict(masknet.state_dict())
        return model

    def train(self, mode: bool = True) -> TwoSidedMaskNet:
        super().train(mode)
        if self.frozen:
            self.masknet.eval()  # frozen BatchNorm statistics too
        return self

    def _local_context(self, source: Tensor) -> Tensor:
        return mlp_pool(self.local, local_offsets(source, self.k))  # (B, M, C)

    def forward(
        self, template: Tensor, source: Tensor, logits: bool = False, template_branch: bool = True
    ) -> tuple[Tensor | None, Tensor]:
        """(B, N, 3), (B, M, 3) -> template scores (B, N), source scores (B, M).

        ``template_branch=False`` skips the template scores (returned as None): training
        a frozen network needs only the source's.
        """
        template, source = centre_pair(template, source, "each")
        net = self.masknet
        with torch.set_grad_enabled(torch.is_grad_enabled() and not self.frozen):
            f_t, f_s = net.encoder(template), net.encoder(source)
        g_t = f_t.amax(dim=1)
        x = (
            self.source_point(f_s)
            + self.source_local(self._local_context(source))
            + self.source_global(g_t)[:, None, :]
        )
        for layer in self.source_head:
            x = layer(torch.relu(x))
        source_logits = x.squeeze(-1)
        if not template_branch:
            return None, source_logits if logits else torch.sigmoid(source_logits)
        # Kept source points (score >= 0.5) enter the max-pool unchanged, rejected ones
        # as zero (features are >= 0 after ReLU). A hard gate, not a soft weight: with
        # every point kept this is exactly the paper's global feature.
        keep = (source_logits.detach() >= 0).to(f_s.dtype)[..., None]
        with torch.set_grad_enabled(torch.is_grad_enabled() and not self.frozen):
            g_s = net.head_global((f_s * keep).amax(dim=1))
            template_logits = net._head_tail(net.head_template(f_t) + g_s[:, None, :])
        if logits:
            return template_logits, source_logits
        return torch.sigmoid(template_logits), torch.sigmoid(source_logits)

    # ------------------------------------------------------------------ numpy inference
    @torch.inference_mode()
    def predict(
        self,
        template: np.ndarray,
        source: np.ndarray,
        precision: Literal["auto", "fp32", "bf16"] = "auto",
        normalize: bool = True,
        pairs_per_call: int = PAIRS_PER_CALL,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Scores for numpy clouds: template (N, 3) or (B, N, 3), source (M, 3) or
        (B, M, 3) -> (template scores (N,) or (B, N), source scores (M,) or (B, M)),
        float32 in [0, 1]. ``normalize`` and ``precision`` as :meth:`MaskNet.predict`."""
        return predict_two_masks(self, template, source, precision, normalize, pairs_per_call)

    def predict_masks(
        self,
        template: np.ndarray,
        source: np.ndarray,
        *,
        k: int | None = None,
        threshold: float | None = None,
        source_threshold: float = 0.5,
        precision: Literal["auto", "fp32", "bf16"] = "auto",
        normalize: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Boolean masks (template (N,) or (B, N), source (M,) or (B, M)).

        Source points are kept where their score is >= ``source_threshold``. The template
        mask is top-k with k = M, the number of source points, as the paper's network
        does, unless ``k`` or ``threshold`` is given (as :meth:`MaskNet.predict_mask`).
        (k = the number of *kept* source points registered worse: on 200 ModelNet40 pairs
        with 10% outliers, 5.73 against 5.54 degrees mean error after one round.)
        """
        t_scores, s_scores = self.predict(template, source, precision, normalize)
        template_mask = select_template_mask(torch.from_numpy(t_scores), source, k, threshold)
        return template_mask.numpy(), s_scores >= source_threshold

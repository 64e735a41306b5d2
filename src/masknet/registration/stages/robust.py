"""``method="robust"``: the coarse-to-fine pipeline, pair by pair.

:func:`robust_register` runs :func:`masknet.registration.stages.search.coarse_to_fine` on each
pair of a batch; the pipeline itself (FPFH hypotheses, early exit, the learned side, one
score, refinement, ambiguity) is described there.

Example::

    result = register(template, source, method="robust")
    result.info["path"], result.info["ambiguous"]
"""

from __future__ import annotations

import numpy as np

from masknet.geometry.sampling import NetworkClouds, spread_labels
from masknet.models.masknet import MaskNet
from masknet.models.two_sided import TwoSidedMaskNet
from masknet.registration.solvers.backends.base import MaskModels
from masknet.registration.stages.search import coarse_to_fine
from masknet.registration.terms.options import RobustOptions
from masknet.registration.terms.result import Solution, info_arrays

__all__ = ["GivenMasks", "NetworkMasks", "pipeline_run", "robust_register"]


class NetworkMasks:
    """The masks of the robust search, answering the one mask protocol
    (:class:`~masknet.registration.stages.refinement.MaskPredictor`): the network runs once on the
    clouds sampled to its size, template_net (n, 3) and source_net (m, 3), and every point
    of the clouds it is asked about takes the label of its nearest sampled point. A
    one-sided MaskNet keeps every source point."""

    def __init__(
        self,
        model: MaskNet | TwoSidedMaskNet,
        template_net: np.ndarray,
        source_net: np.ndarray,
        precision: str = "auto",
    ) -> None:
        self.model, self.precision = model, precision
        self.template_net, self.source_net = template_net, source_net

    def predict_masks(
        self, template: np.ndarray, source: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        t_mask, s_mask = self.model.predict_masks(
            self.template_net, self.source_net, precision=self.precision
        )
        if s_mask is None:  # a one-sided network keeps every source point
            s_mask = np.ones(len(self.source_net), bool)
        return (
            spread_labels(template, self.template_net, t_mask),
            spread_labels(source, self.source_net, s_mask),
        )


class GivenMasks:
    """Masks already predicted (the fast path's, where its network is the search's),
    answering the mask protocol: template (n,) and source
    (1, m) or None, for the clouds they were predicted on."""

    def __init__(self, mask: np.ndarray, source_mask: np.ndarray | None) -> None:
        self.masks = mask, None if source_mask is None else source_mask[0]

    def predict_masks(
        self, template: np.ndarray, source: np.ndarray, **_: object
    ) -> tuple[np.ndarray, np.ndarray | None]:
        return self.masks


def robust_register(
    template: np.ndarray,
    source: np.ndarray,
    nets: NetworkClouds,
    models: MaskModels,
    options: RobustOptions,
    times: dict[str, float],
    precision: str = "auto",
) -> Solution:
    """The coarse-to-fine pipeline for template (B, N, 3) and source (B, M, 3), float64,
    one pair at a time, at full resolution; the network (``models.first``, None: no masks)
    sees ``nets`` (B, n, 3) and (B, m, 3), the clouds sampled to its size.
    Masks are over the full clouds. Stage times are summed into ``times``. The method
    table's adapter of ``"robust"``."""
    model = models.first
    runs = []
    for b in range(template.shape[0]):
        masks = None
        if model is not None:
            masks = NetworkMasks(model, nets.template[b], nets.source[b], precision)
        runs.append(coarse_to_fine(template[b], source[b], masks, options, times))
    return pipeline_run(runs)


def pipeline_run(runs: list[Solution]) -> Solution:
    """A batch's :class:`~masknet.registration.terms.result.Solution` from each pair's."""
    masks = [r.mask for r in runs]
    source_masks = [r.source_mask for r in runs]
    return Solution(
        np.stack([r.transform for r in runs]),
        None if any(m is None for m in masks) else np.stack(masks),
        None if any(m is None for m in source_masks) else np.stack(source_masks),
        info_arrays([r.info for r in runs]),
    )

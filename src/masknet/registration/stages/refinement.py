"""The masks of rounds >= 2: both inlier masks of a pair that registration has brought close.

Round 1 of Mask-X masks the template with MaskNet, which centres each cloud on its own
centroid and so cannot see the pose. From round 2 on the source has been moved by the
current estimate, so relative position is information. A *refiner* turns the pair, in
that one frame, into a template mask and a source mask; both have the protocol

    predict_masks(template (B, N, 3), source (B, M, 3)) -> (template (B, N) bool,
                                                             source (B, M) bool)

Two refiners:

* :class:`NearestNeighbourMasks`, the geometric rule: source points near the template
  are kept, and as many template points as there are kept source points, those nearest
  the kept source.
* :class:`~masknet.models.refine.RefineMaskNet`, the learned refinement mask, which takes
  the same distances among its inputs: the default. Against the rule at the same residual
  poses it is more precise everywhere but on clean pairs within 2 degrees of the truth,
  and rejects more outliers; in three rounds of Mask-ICP it ends closer, at about twice
  the rule's time (docs/RESULTS.md, "Masks per round").

:func:`resolve_refiner` maps ``register``'s ``refine_masks`` argument onto one.
"""

from __future__ import annotations

import functools
import time
from typing import Any, Protocol

import numpy as np

from masknet._moved import moved_names
from masknet.errors import MaskNetError
from masknet.geometry.clouds import median_spacing
from masknet.geometry.se3 import transform_points
from masknet.registration.terms.result import Solution

__all__ = [
    "DEFAULT_REFINER",
    "REFINERS",
    "NearestNeighbourMasks",
    "MaskPredictor",
    "Refiner",
    "refine_pose",
    "resolve_refiner",
]

# ``refine_masks`` by name: the rule, the shipped learned refiner, or the first round's
# network again (the paper's loop).
REFINERS = ("nearest", "learned", "network")
DEFAULT_REFINER = "learned"  # measured against the rule in docs/RESULTS.md
# After a pipeline the learned refiner's template mask is its scores >= this, not the top k
# with k the source points kept: two partial scans (3DMatch) share only part of each, and k
# then covers most of the template (on the 3DMatch pair precision 0.69 against 0.42).
# Confirmed on the training scans the refiner held out: the lowest of a grid of thresholds
# with precision >= 0.95 on 70% views there, shared points or re-sampled (scripts/mask_precision_ceiling.py
# --validation; docs/RESULTS.md, "How precise the loop's mask can be").
TEMPLATE_THRESHOLD = 0.9
# The refined rounds' ICP pairs the kept source with the template points scoring at least
# this, the network's own decision boundary, not TEMPLATE_THRESHOLD: a true partner left
# out pulls its source point onto a neighbour (a bias), where a false one is mostly cut by
# the pair distance. On 300 clean ModelNet40 pairs the default's three rounds ended 0.069
# degrees off with the mask returned, 0.011 with this one; on the scan pairs the means
# moved within their noise (docs/RESULTS.md, "Masks per round").
ICP_THRESHOLD = 0.5


class MaskPredictor(Protocol):
    """The one mask protocol: ``predict_masks(template, source) -> (template mask, source
    mask)``, bool over the points it is given. The networks answer it (MaskNet's source
    mask is None: it keeps every source point), and so do the refiners of rounds >= 2 (on a
    pair in one frame, see the module docstring), the robust search's network masks
    (:class:`masknet.registration.stages.robust.NetworkMasks`) and masks given in advance."""

    def predict_masks(
        self, template: np.ndarray, source: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray | None]: ...


# A refiner is a mask predictor for a pair that registration has brought close.
Refiner = MaskPredictor


class NearestNeighbourMasks:
    """The nearest-neighbour rule for a pair in one frame.

    A source point is kept when its nearest template point lies within
    ``max(source_spacings * s, source_median_factor * median)``, where ``s`` is the
    template's median point spacing and ``median`` the median of those distances over the
    source (a residual pose moves every point, so the cut-off grows with it). The template
    mask is the ``k`` template points nearest the kept source, ``k`` the number of kept
    source points (MaskNet's top-k rule; :func:`masknet.register` samples a large source
    at the template's spacing, so the counts compare).
    """

    def __init__(self, source_spacings: float = 3.0, source_median_factor: float = 3.0) -> None:
        if not source_spacings > 0 or not source_median_factor > 0:
            raise MaskNetError("the rule's distance factors must be positive")
        self.source_spacings = source_spacings
        self.source_median_factor = source_median_factor

    def predict_masks(
        self, template: np.ndarray, source: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """template (N, 3) or (B, N, 3), source (M, 3) or (B, M, 3) in one frame ->
        (template mask (N,) or (B, N), source mask (M,) or (B, M)), bool."""
        t, s = np.asarray(template, np.float64), np.asarray(source, np.float64)
        if t.ndim == 2:
            masks = self.predict_masks(t[None], s[None])
            return masks[0][0], masks[1][0]
        pairs = [self._pair(t[i], s[i]) for i in range(t.shape[0])]
        return np.stack([p[0] for p in pairs]), np.stack([p[1] for p in pairs])

    def _pair(self, template: np.ndarray, source: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        from masknet.geometry.knn import cloud_tree

        t_tree = cloud_tree(template)
        t_spacing = median_spacing(template, t_tree)
        d_source = t_tree.query(source, k=1)[0]
        cut = max(self.source_spacings * t_spacing, self.source_median_factor * np.median(d_source))
        source_mask = d_source <= cut
        if source_mask.sum() < 3:  # nothing sensible to keep: keep everything
            source_mask[:] = True
        kept = source[source_mask]
        k = int(np.clip(len(kept), 3, len(template)))
        d_template = cloud_tree(kept).query(template, k=1)[0]
        template_mask = np.zeros(len(template), bool)
        template_mask[np.argsort(d_template, kind="stable")[:k]] = True
        return template_mask, source_mask


@functools.cache
def _shipped_refiner() -> Any:
    from masknet.models.refine import RefineMaskNet

    return RefineMaskNet.pretrained()


def resolve_refiner(spec: Any, first_round_model: Any) -> Refiner | None:
    """The refiner that ``refine_masks=spec`` names; None means the first round's network
    again (``"network"``, the paper's loop) or no mask at all (no first-round model)."""
    if isinstance(spec, str) and spec not in REFINERS:
        raise MaskNetError(f"unknown refine_masks {spec!r}; choose from {REFINERS}")
    if (
        spec is not None
        and not isinstance(spec, str)
        and not callable(getattr(spec, "predict_masks", None))
    ):
        raise MaskNetError(
            "refine_masks must be one of "
            f"{REFINERS} or an object with predict_masks(template, source)"
        )
    if first_round_model is None or spec is None or spec == "network":
        return None
    if spec == "nearest":
        return NearestNeighbourMasks()
    if spec == "learned":
        return _shipped_refiner()
    return spec


def refine_pose(
    template: np.ndarray,
    source: np.ndarray,
    sampled: tuple[np.ndarray, np.ndarray],
    start: np.ndarray,
    refiner: Refiner | None,
    rounds: int,
    cut: float,
    times: dict[str, float],
    max_iterations: int = 10,
) -> Solution:
    """Refined Mask-ICP rounds from a pose another stage found, for one pair.

    Each round the refiner masks the pair as it stands (on ``sampled``, its masks spread to
    every point; the learned refiner's template mask is its scores >= TEMPLATE_THRESHOLD,
    and ICP pairs with the wider set >= ICP_THRESHOLD), then point-to-plane ICP (the
    template's PCA normals) runs on the masked points at full
    resolution, pairs cut at ``cut``, from the pose reached: the masks drop what the source
    does not share with the template, the cut-off what a mask missed, and the planes keep
    a source sampled apart from the template from being pulled onto its sample points
    (point-to-point ICP stops about 0.5 degrees off on such real-scan pairs). A round whose
    pose fits worse than its start by more than FIT_SLACK is undone and ends the rounds.

    Args:
        template: (N, 3) float64, the full template. source: (M, 3) float64, likewise.
        sampled: indices (n,) and (m,) of the points the refiner sees.
        start: (4, 4) source -> template pose to start from.
        refiner: the masks of each round, or None (plain ICP rounds).
        rounds: how many rounds (>= 1).
        cut: ICP's max_correspondence_distance, in the clouds' units.
        times: seconds are added to ``"mask"`` and ``"register"``.
        max_iterations: ICP's, per round.
    """
    from masknet.geometry.knn import cloud_tree
    from masknet.geometry.normals import estimate_normals
    from masknet.geometry.sampling import nearest_sample
    from masknet.registration.judge.arbiter import fits_worse
    from masknet.registration.judge.fit import pose_fit
    from masknet.registration.solvers.icp import icp

    template_index, source_index = sampled
    # Each point takes the label of its nearest sample: found once for every round's masks.
    template_nearest = nearest_sample(template, template_index)
    source_nearest = nearest_sample(source, source_index)
    template_net = template[template_index][None]
    total = np.asarray(start, np.float64)
    mask = source_mask = None
    tree = cloud_tree(template)
    normals = estimate_normals(template, tree=tree)[0]
    history = []

    def masks_at(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The template mask returned, the source mask, and the template mask ICP uses."""
        tic = time.perf_counter()
        moved = transform_points(pose, source[source_index]).reshape(1, -1, 3)
        t_mask, s_mask, t_icp = _masks(refiner, template_net, moved)
        full = (
            t_mask[0][template_nearest],
            s_mask[0][source_nearest],
            t_icp[0][template_nearest],
        )
        times["mask"] += time.perf_counter() - tic
        return full

    probe = source[source_index]  # the fit of a pose, on the points the refiner sees
    fit = pose_fit(tree, probe, total, cut).score
    settled = False
    for _ in range(rounds):
        if settled:  # a round that fitted worse was undone: the pose stays
            history.append(total.copy())
            continue
        icp_mask = None
        if refiner is not None:
            mask, source_mask, icp_mask = masks_at(total)
        tic = time.perf_counter()
        masked = icp_mask is not None and icp_mask.sum() >= 3  # else the whole template
        solution = icp(
            template[icp_mask] if masked else template,
            source,
            total,
            max_iterations=max_iterations,
            max_correspondence_distance=cut,
            source_valid=source_mask,
            template_tree=None if masked else tree,
            template_normals=normals[icp_mask] if masked else normals,
        )
        moved_to = np.asarray(solution.transform).reshape(4, 4)
        new_fit = pose_fit(tree, probe, moved_to, cut).score
        # Point-to-plane steps on a sparse shape's poor normals can slide far (one of 300
        # ModelNet40 pairs: 3 -> 104 degrees, its fit 0.85 -> 0); a better pose on re-sampled
        # scans fits about as well (within 0.007) by this point-to-point measure.
        if fits_worse(new_fit, fit):
            settled = True
        else:
            total, fit = moved_to, new_fit
        history.append(total.copy())
        times["register"] += time.perf_counter() - tic
    if refiner is not None:
        mask, source_mask, _ = masks_at(total)
    return Solution(total, mask, source_mask, rounds=history)


def _masks(refiner: Refiner, template: np.ndarray, source: np.ndarray) -> tuple:
    """(template mask, source mask, template mask for ICP): a learned refiner's template
    masks are its scores >= TEMPLATE_THRESHOLD and >= ICP_THRESHOLD, from one pass; any
    other refiner's one template mask serves both."""
    from masknet.models.refine import RefineMaskNet, masks_from_scores

    if isinstance(refiner, RefineMaskNet):
        t_scores, s_scores = refiner.predict(template, source)
        mask, source_mask = masks_from_scores(t_scores, s_scores, threshold=TEMPLATE_THRESHOLD)
        icp_mask, _ = masks_from_scores(t_scores, s_scores, threshold=ICP_THRESHOLD)
        return mask, source_mask, icp_mask
    mask, source_mask = refiner.predict_masks(template, source)
    return mask, source_mask, mask


# Moved to the one fit module.
__getattr__ = moved_names(__name__, {"FIT_SLACK": "masknet.registration.judge.fit"})

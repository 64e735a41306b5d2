"""``method="robust"``: Mask-ICP from many rotation hypotheses, scored, then refined.

ICP, masked or not, converges to the nearest local minimum: from a rotation far from
the truth it stops at a wrong pose, and those stops make the tail of its errors. The
robust pipeline, for each pair:

1. Scale: both clouds are centred (the source on its median, so outliers and clutter
   move it little) and divided by the template's radius, so the result does not
   depend on the unit.
2. Hypotheses: the source is turned by each of ``hypotheses`` rotations (the 24
   rotations of the cube by default, which leave no orientation more than 62.8
   degrees from one of them), and every hypothesis runs ``mask_rounds`` rounds of ICP
   (of Mask-ICP with ``hypothesis_mask=True``), all in one batched call, on
   ``hypothesis_points`` points per cloud.
3. Scoring: each result is scored by a trimmed fit: the mean squared distance of
   the best ``trim`` fraction of source points (the kept ones, for a two-sided
   MaskNet) to the template, plus the same for the masked template points to the
   source, so that neither a source sunk inside a large template nor one covering a
   small part of it scores well.
4. Refinement: the ``candidates`` best hypotheses run ``mask_rounds`` more rounds of
   Mask-ICP at full resolution and end with ICP on the whole template whose pairs are
   cut at ``inlier_distance`` (in template radii): a geometric inlier mask, once the
   clouds are close. They are scored again, and the best is the result. (At the coarse
   stage a symmetric shape's flipped pose can score as well as the right one; after
   refinement the right one fits better.)

The mask is the two-sided MaskNet's by default (``register`` loads
``masknet2_scans``), so outliers and clutter in the source neither steer ICP nor
count in the score; a paper MaskNet passed as ``model`` masks the template only.

Cost (defaults, one pair of 1,024 points, 2 CPU threads): about 20 single Mask-ICP
calls: 24 plain ICPs at 256 points in one batch, then 6 candidates through two rounds
of two-sided Mask-ICP and 30 refinement iterations at full resolution.

Example::

    result = register(template, source, method="robust")
    result = register(template, source, method="robust", hypotheses=12, candidates=4)
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from masknet.geometry.clouds import unit_radius
from masknet.geometry.knn import knn_points
from masknet.geometry.sampling import farthest_point_sample
from masknet.models.masknet import MaskNet
from masknet.models.two_sided import TwoSidedMaskNet
from masknet.registration.backends import run_icp
from masknet.registration.options import RobustOptions
from masknet.registration.refinement import Refiner
from masknet.registration.rounds import apply_transform, keep_source_points, mask_and_register

__all__ = [
    "hypothesis_rotations",
    "robust_register",
    "trimmed_fit",
    "trimmed_mean",
    "trimmed_order",
]


class RobustRun(NamedTuple):
    """transform: (B, 4, 4) source -> template. mask: (B, N) template points in use in
    the last round (None without a model). source_mask: (B, M) for a two-sided MaskNet.
    info: (B,) arrays: ``fitness`` and ``inlier_rmse`` of the final ICP,
    ``hypothesis`` (index of the chosen rotation) and ``score`` (its trimmed fit, in
    squared template radii)."""

    transform: np.ndarray
    mask: np.ndarray | None
    source_mask: np.ndarray | None
    info: dict[str, np.ndarray]


@functools.cache
def hypothesis_rotations(count: int) -> np.ndarray:
    """(count, 3, 3) starting rotations: the 24 rotations of the cube, nearest the
    identity first, then seeded random rotations."""
    cube = Rotation.create_group("O").as_matrix()
    angles = np.arccos(np.clip((np.trace(cube, axis1=1, axis2=2) - 1) / 2, -1, 1))
    cube = cube[np.argsort(angles, kind="stable")]
    if count <= len(cube):
        return cube[:count]
    extra = Rotation.random(count - len(cube), random_state=0).as_matrix()
    return np.concatenate([cube, extra])


def _subsample(points: np.ndarray, count: int) -> np.ndarray:
    """(B, P, 3) -> (B, min(P, count), 3) by farthest point sampling, pair by pair."""
    if points.shape[1] <= count:
        return points
    return np.stack([p[farthest_point_sample(p, count).indices] for p in points])


def trimmed_order(
    d2: np.ndarray, trim: float, valid: np.ndarray, min_keep: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Each row of (B, P) squared distances sorted, invalid entries (``valid`` (B, P)
    False) last as inf, and how many of each row the ``trim`` fraction of its valid
    entries keeps (B,), at least ``min_keep``."""
    ordered = np.sort(np.where(valid, d2, np.inf), axis=1)
    keep = np.maximum(min_keep, np.round(trim * valid.sum(1))).astype(np.int64)
    return ordered, keep


def trimmed_mean(d2: np.ndarray, trim: float, valid: np.ndarray | None = None) -> np.ndarray:
    """Mean of the smallest ``trim`` fraction of each row of (B, P) squared distances: (B,).

    ``valid`` (B, P) bool limits each row to its valid entries (the fraction is of those);
    a row without any is inf.
    """
    if valid is None:
        keep = max(1, int(round(trim * d2.shape[1])))
        return np.sort(d2, axis=1)[:, :keep].mean(1)
    ordered, keep = trimmed_order(d2, trim, valid)
    sums = np.cumsum(np.where(np.isfinite(ordered), ordered, 0.0), axis=1)
    means = sums[np.arange(len(d2)), keep - 1] / keep
    return np.where(valid.any(1), means, np.inf)


def trimmed_fit(query: np.ndarray, reference: np.ndarray, trim: float) -> np.ndarray:
    """Mean squared distance of the best ``trim`` fraction of query points (B, P, 3) to
    their nearest reference point (B, R, 3): (B,)."""
    d2 = knn_points(torch.from_numpy(query), torch.from_numpy(reference), 1).dists[..., 0]
    return trimmed_mean(d2.numpy(), trim)


def _score(
    template: np.ndarray,
    moved: np.ndarray,
    mask: np.ndarray | None,
    source_mask: np.ndarray | None,
    trim: float,
) -> np.ndarray:
    """Trimmed fit both ways (B,): kept source -> template, masked template -> source."""
    if mask is None and source_mask is None:  # same sizes everywhere: one batched search
        return trimmed_fit(moved, template, trim) + trimmed_fit(template, moved, trim)
    scores = np.empty(template.shape[0])
    for b in range(template.shape[0]):  # masks differ in size between hypotheses
        src = moved[b] if source_mask is None else moved[b][source_mask[b]]
        tpl = template[b] if mask is None else template[b][mask[b]]
        if len(src) < 3 or len(tpl) < 3:
            scores[b] = np.inf
            continue
        scores[b] = (
            trimmed_fit(src[None], template[b][None], trim)[0]
            + trimmed_fit(tpl[None], src[None], trim)[0]
        )
    return scores


def robust_register(
    template: np.ndarray,
    source: np.ndarray,
    model: MaskNet | TwoSidedMaskNet | None,
    options: RobustOptions,
    times: dict[str, float],
    precision: str = "auto",
    refiner: Refiner | None = None,
) -> RobustRun:
    """The robust pipeline (module docstring) for template (B, N, 3), source (B, M, 3),
    float64; ``model`` None runs plain ICP from every hypothesis. ``refiner`` masks the
    candidates' rounds >= 2 (:mod:`masknet.registration.refinement`)."""
    options.check()
    b = template.shape[0]
    # 1. Unit-free frame: template centroid and source median at the origin, radius 1.
    tpl_centre = template.mean(axis=1, keepdims=True)
    src_centre = np.median(source, axis=1, keepdims=True)
    scale = unit_radius(torch.from_numpy(template)).numpy()[:, None, None]
    tpl_n = (template - tpl_centre) / scale
    src_n = (source - src_centre) / scale

    # 2. Every hypothesis of every pair in one batch, at hypothesis resolution.
    rotations = hypothesis_rotations(options.hypotheses)
    h = len(rotations)
    tpl_small = np.repeat(_subsample(tpl_n, options.hypothesis_points), h, axis=0)
    src_small = np.repeat(_subsample(src_n, options.hypothesis_points), h, axis=0)
    starts = np.tile(np.eye(4), (b * h, 1, 1))
    starts[:, :3, :3] = np.tile(rotations, (b, 1, 1))
    icp_options = {"max_iterations": options.max_iterations}
    stage = mask_and_register(
        tpl_small,
        src_small,
        "icp",
        model if options.hypothesis_mask else None,
        options.mask_rounds,
        icp_options,
        times,
        precision=precision,
        start=starts,
    )
    # 3. Trimmed fit of each hypothesis; the best few per pair go on.
    moved = apply_transform(stage.transform, src_small)
    scores = _score(tpl_small, moved, stage.mask, stage.source_mask, options.trim).reshape(b, h)
    c = min(options.candidates, h)
    picks = np.argsort(scores, axis=1, kind="stable")[:, :c]  # (B, C)
    # The unturned start always goes on: near the truth it is the likeliest.
    absent = ~(picks == 0).any(axis=1)
    picks[absent, -1] = 0
    chosen = stage.transform.reshape(b, h, 4, 4)[np.arange(b)[:, None], picks].reshape(b * c, 4, 4)

    # 4. The candidates at full resolution, then the geometric-inlier ICP; rescored.
    tpl_c, src_c = np.repeat(tpl_n, c, axis=0), np.repeat(src_n, c, axis=0)
    final = mask_and_register(
        tpl_c,
        src_c,
        "icp",
        model,
        options.mask_rounds,
        icp_options,
        times,
        precision=precision,
        start=chosen,
        refiner=refiner,
    )
    total, run_info = final.transform, final.run.info
    kept = final.source_mask
    if options.inlier_iterations:
        refine = {
            "max_iterations": options.inlier_iterations,
            "max_correspondence_distance": options.inlier_distance,
        }
        moved = apply_transform(total, src_c)
        if kept is not None:
            moved = keep_source_points(moved, kept)
        run = run_icp(tpl_c, moved, None, refine)
        total, run_info = run.transform @ total, run.info
    moved = apply_transform(total, src_c)
    final_scores = _score(tpl_c, moved, final.mask, kept, options.trim).reshape(b, c)
    best = final_scores.argmin(axis=1)
    # Another hypothesis replaces the unturned start only if it fits clearly better: a
    # partial view can fit a wrong part of a smooth surface almost as well.
    start = (picks == 0).argmax(axis=1)
    keep_start = (
        final_scores[np.arange(b), best]
        > options.identity_margin * final_scores[np.arange(b), start]
    )
    best = np.where(keep_start, start, best)
    flat = np.arange(b) * c + best
    total = total[flat]
    info = {
        "hypothesis": picks[np.arange(b), best],
        "score": final_scores[np.arange(b), best],
        "fitness": run_info["fitness"][flat],
        "inlier_rmse": run_info["inlier_rmse"][flat] * scale[:, 0, 0],
    }
    mask = None if final.mask is None else final.mask[flat]
    source_mask = None if kept is None else kept[flat]
    # Back to the input frame: x -> c_t + s * T_n((x - c_s) / s).
    out = total.copy()
    out[:, :3, 3] = (
        tpl_centre[:, 0]
        + scale[:, 0] * total[:, :3, 3]
        - np.einsum("bij,bj->bi", total[:, :3, :3], src_centre[:, 0])
    )
    return RobustRun(out, mask, source_mask, info)

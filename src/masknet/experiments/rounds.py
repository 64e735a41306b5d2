"""``masks-per-round`` and ``refine-masks``: what the masks of the iterative loop are worth.

* ``masks-per-round``: mask precision and recall (template and source) and rotation
  error after rounds 1..3 of Mask-ICP, for the paper's loop (MaskNet in every round),
  the nearest-neighbour rule and the learned refinement mask in rounds >= 2, beside plain
  ICP given the same 30 iterations; on ModelNet40 (clean, noise 0.01, 10% outliers) and
  on pairs cut from the evaluation scans, with and without shared points.
* ``refine-masks``: the learned refinement mask against the nearest-neighbour rule on
  the same pairs, moved onto the template by the true pose and off it again by a fixed
  residual rotation (0-20 degrees), in several conditions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from masknet.data.pairs import PairConfig, Pairs, derive_seed
from masknet.data.residuals import turned_pairs
from masknet.data.scans import Scan, load_scans, make_scan_test_pairs
from masknet.data.views import ViewConfig
from masknet.errors import MaskNetError
from masknet.evaluation.registration import pair_arrays, pose_errors
from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.experiments.plots import panel_plot
from masknet.experiments.scans import scans_folder
from masknet.models.masknet import MaskNet
from masknet.models.two_sided import TwoSidedMaskNet
from masknet.registration.api import register
from masknet.registration.stages.refinement import NearestNeighbourMasks

__all__ = [
    "masks_per_round",
    "refine_masks",
    "refiner_row",
    "refiner_table",
    "residual_moved",
    "scan_eval_pairs",
    "scan_eval_set",
]

ROUNDS = 3
# Name -> register() keywords; each masked pipeline runs ROUNDS rounds, plain ICP gets their
# iterations in one run. "paper" marks the paper's loop: its MaskNet in every round.
# "default" rows start from the default pipeline's answer (register(..., iterations=3) with
# no method), with learned refined rounds or, to isolate what the masks add, plain ICP rounds.
PIPELINES = {
    "ICP, 30 iterations": {"method": "icp", "use_mask": False, "max_iterations": 30},
    "default, then refined Mask-ICP": {"default": True},
    "default, then plain ICP": {"default": True, "refine_masks": None},
    "Mask-ICP, paper's loop": {"method": "icp", "refine_masks": "network", "paper": True},
    "Mask-ICP, nearest rule": {"method": "icp", "refine_masks": "nearest"},
    "Mask-ICP, learned": {"method": "icp", "refine_masks": "learned"},
    "PointNetLK, 3 rounds": {"method": "pointnetlk", "use_mask": False, "rounds": ROUNDS},
    "Mask-PointNetLK, paper's loop": {
        "method": "pointnetlk",
        "refine_masks": "network",
        "paper": True,
    },
    "Mask-PointNetLK, nearest rule": {"method": "pointnetlk", "refine_masks": "nearest"},
    "Mask-PointNetLK, learned": {"method": "pointnetlk", "refine_masks": "learned"},
}
SCAN_TEMPLATE_POINTS = 4096
# --quick (a smoke run): ModelNet40 pairs per set, and the first scan pairs of one kind
QUICK_MODELNET_PAIRS = 4
QUICK_SCAN_PAIRS = 2


def scan_eval_pairs(count_per_scan: int, shared: bool, seed: int) -> Pairs:
    """Pairs cut from the evaluation scans (``$MASKNET_SCANS``, default
    ../shared/data/scans): 70% views of 4,096-point templates, rotations up to 45 degrees,
    translations up to 0.5 radius, noise 0.2% of the radius; the source re-sampled
    (``shared=False``) or copied from the template's points. :func:`scan_eval_set` takes
    another folder and names each pair's scan."""
    return scan_eval_set(count_per_scan, shared, seed)[0]


def scan_eval_set(
    count_per_scan: int,
    shared: bool,
    seed: int,
    folder: Path | None = None,
    names: list[str] | None = None,
) -> tuple[Pairs, list[str]]:
    """:func:`scan_eval_pairs` from ``folder`` (default ``$MASKNET_SCANS`` or
    ../shared/data/scans; only the scans called ``names`` where given), and the name of
    the scan each pair was cut from."""
    folder = scans_folder() if folder is None else Path(folder)
    if not folder.is_dir():
        raise MaskNetError(f"{folder}: scan folder not found; set MASKNET_SCANS")
    view = ViewConfig(
        template_points=SCAN_TEMPLATE_POINTS,
        max_translation=0.5,
        noise_sigma=0.002,
        independent=not shared,
    )
    scans: list[Scan] = [
        s
        for s in load_scans(folder, quiet=True)
        if len(s) >= view.min_cloud_points and (names is None or s.name in names)
    ]
    if not scans:
        raise MaskNetError(f"{folder}: no scan of {view.min_cloud_points} points or more")
    missing = sorted(set(names or ()) - {s.name for s in scans})
    if missing:
        raise MaskNetError(
            f"{folder}: scans {', '.join(missing)} missing or under {view.min_cloud_points} points"
        )
    return make_scan_test_pairs(scans, count_per_scan, view, seed=seed)


def _sets(ctx: BenchmarkContext, modelnet_pairs: int, per_scan: int) -> dict[str, Pairs]:
    sets = {
        "ModelNet40 clean": ctx.test_pairs(PairConfig(), modelnet_pairs),
        "ModelNet40 noise 0.01": ctx.test_pairs(PairConfig(noise_sigma=0.01), modelnet_pairs),
        "ModelNet40 10% outliers": ctx.test_pairs(PairConfig(outlier_ratio=0.1), modelnet_pairs),
    }
    if scans_folder().is_dir():  # the evaluation scans, where they are (CI has them)
        kinds = ((True, "scans, shared points"), (False, "scans, re-sampled"))
        for shared, name in kinds[:1] if ctx.quick else kinds:  # quick: one kind suffices
            pairs = scan_eval_pairs(per_scan, shared, ctx.seed)
            sets[name] = pairs.rows(slice(QUICK_SCAN_PAIRS)) if ctx.quick else pairs
    return sets


def _precision_recall(predicted: np.ndarray | None, truth: np.ndarray) -> tuple[float, float]:
    if predicted is None:
        return float("nan"), float("nan")
    tp = int((predicted & truth).sum())
    return tp / max(int(predicted.sum()), 1), tp / max(int(truth.sum()), 1)


def _pipeline_rows(pairs: Pairs, kwargs: dict) -> dict:
    """Per round r: the precision and recall of the masks that ``register(...,
    iterations=r)`` returns (template, and source points kept), and rotation errors."""
    template, source, truth = pair_arrays(pairs)
    masks, source_masks = pairs.mask.numpy(), pairs.source_mask.numpy()
    kwargs = dict(kwargs)
    masked = kwargs.get("use_mask", True)
    if kwargs.pop("paper", False):
        kwargs["model"] = MaskNet.pretrained()
    elif kwargs.pop("default", False):
        pass  # the default pipeline picks its own networks
    elif masked:  # the loop's first round in every call, whatever its number of rounds
        kwargs["model"] = TwoSidedMaskNet.pretrained()
    rounds = kwargs.pop("rounds", ROUNDS if masked else 1)
    per_round = np.empty((rounds, len(truth), 4, 4))
    stats = np.full((rounds, len(truth), 4), np.nan)
    for i in range(len(truth)):
        full = register(template[i], source[i], iterations=rounds, **kwargs)
        per_round[:, i] = np.stack(full.rounds)
        for r in range(rounds) if masked else []:
            result = (
                full
                if r == rounds - 1
                else register(template[i], source[i], iterations=r + 1, **kwargs)
            )
            stats[r, i, :2] = _precision_recall(result.mask, masks[i])
            kept = result.source_mask
            stats[r, i, 2:] = _precision_recall(
                np.ones(len(source[i]), bool) if kept is None else kept, source_masks[i]
            )
    out = []
    for r in range(rounds) if masked else [rounds - 1]:
        rot, _ = pose_errors(per_round[r], truth)
        known = ~np.isnan(stats[r]).all(0)  # plain ICP rounds after a pipeline have no mask
        p = np.full(4, np.nan)
        if masked:
            p[known] = np.nanmean(stats[r][:, known], axis=0)
        out.append(
            {
                "round": r + 1 if rounds > 1 else ROUNDS,
                "precision": float(p[0]),
                "recall": float(p[1]),
                "source_precision": float(p[2]),
                "source_recall": float(p[3]),
                "rot_mean": float(rot.mean()),
                "rot_median": float(np.median(rot)),
                "rot_p90": float(np.percentile(rot, 90)),
            }
        )
    return {"rounds": out}


def masks_per_round(ctx: BenchmarkContext) -> ExperimentResult:
    """Mask precision and rotation error per round of Mask-ICP, by refinement mask."""
    modelnet_pairs = QUICK_MODELNET_PAIRS if ctx.quick else min(ctx.pairs, 300)
    per_scan = 1 if ctx.quick else 15
    rows = []
    for set_name, pairs in _sets(ctx, modelnet_pairs, per_scan).items():
        for name, kwargs in PIPELINES.items():
            kept = ctx.row({"set": set_name, "pipeline": name}, _pipeline_rows, pairs, kwargs)
            rows += [{"set": set_name, "pipeline": name, **row} for row in kept["rounds"]]

    def plot(path: Path) -> None:
        loops = [
            p
            for p in PIPELINES
            if p.startswith("Mask-ICP") or p == "default, then refined Mask-ICP"
        ]
        panels = {
            s: {
                p.removeprefix("Mask-ICP, ").removesuffix(", then refined Mask-ICP"): [
                    r["precision"] for r in rows if r["set"] == s and r["pipeline"] == p
                ]
                for p in loops
            }
            for s in dict.fromkeys(r["set"] for r in rows)
        }
        panel_plot(
            path, [1, 2, 3], panels, "round", "mask precision", "Mask-ICP: template mask per round"
        )

    summary = (
        f"{modelnet_pairs} ModelNet40 test pairs per set (paper protocol) and "
        + (
            f"{QUICK_SCAN_PAIRS} scan pairs (quick)"
            if ctx.quick
            else f"{per_scan} pairs per evaluation scan"
        )
        + " (70% views of 4,096-point templates, <= 45 degrees, noise 0.2% of "
        "the radius). The paper's loop runs its MaskNet in every round, each cloud centred on "
        "its own centroid. 'nearest rule' and 'learned' are register(..., method=X, iterations=3) with "
        "refine_masks set: the two-sided network in round 1, then both masks taken on the pair "
        "as the last round left it, and the returned masks those of the pose returned. Plain "
        "ICP gets the 30 iterations of three Mask-ICP rounds; PointNetLK three rounds. "
        "Round r's precision and recall are of the template mask that register(..., "
        "iterations=r) returns (the refined loops': the refiner's, at the pose round r "
        "reached; round 1 and the paper's loop: the mask that round used), source_* of the "
        "source points kept (all of them where no source mask exists); errors in degrees. "
        "'default, then ...' rows are register(..., iterations=3) with no method: round 1 is "
        "the default pipeline's answer (its fast path, or the robust search it escalates to), "
        "then two rounds of point-to-plane ICP at full resolution with pairs cut at 1.5 "
        "template spacings, on the points the learned refiner keeps or, in the plain rows, on "
        "every point (a round that fits worse than its start is undone)."
    )
    return ExperimentResult(rows, summary, plot)


# ----------------------------------------------------------------- refiner against the rule
RESIDUALS_DEG = (0.0, 2.0, 5.0, 10.0, 20.0)


def residual_moved(pairs: Pairs, angle_deg: float, seed: int) -> np.ndarray:
    """The sources (P, M, 3) moved onto their templates by the true pose, then turned by
    ``angle_deg`` about a random axis through their centroid."""
    gen = torch.Generator().manual_seed(derive_seed(seed, int(angle_deg * 1000)))
    return turned_pairs(pairs, angle_deg, gen).source.double().numpy()


def _conditions(ctx: BenchmarkContext, count: int, per_scan: int) -> dict[str, Pairs]:
    sets = _sets(ctx, count, per_scan)
    sets["ModelNet40 views, re-sampled"] = _resampled(ctx, count)
    return sets


def _resampled(ctx: BenchmarkContext, count: int) -> Pairs:
    """Sensor-like ModelNet40 views: sampled apart from their 512-point templates, density
    falling off with the distance to the viewpoint, noise 0.005 of the radius."""
    from masknet.data.views import make_view_pairs, normalize_cloud

    rng = np.random.default_rng(derive_seed(ctx.seed, 0xD5))
    picks = rng.permutation(len(ctx.points))[:count]
    view = ViewConfig(template_points=512, noise_sigma=0.005)
    return make_view_pairs([normalize_cloud(ctx.points[i]) for i in picks], view, rng)


def refiner_row(pairs: Pairs, angle: float, seed: int, refiners: dict) -> dict:
    moved = residual_moved(pairs, angle, seed)
    template = pairs.template.double().numpy()
    truth_t, truth_s = pairs.mask.numpy(), pairs.source_mask.numpy()
    row = {}
    for name, refiner in refiners.items():
        t_mask, s_mask = refiner.predict_masks(template, moved)
        p = [_precision_recall(t_mask[i], truth_t[i]) for i in range(len(template))]
        row[f"{name}_precision"] = float(np.mean([x[0] for x in p]))
        row[f"{name}_recall"] = float(np.mean([x[1] for x in p]))
        rejected = ~s_mask & ~truth_s
        row[f"{name}_outliers_removed"] = (
            float(rejected.sum() / (~truth_s).sum()) if (~truth_s).any() else float("nan")
        )
        row[f"{name}_real_kept"] = float((s_mask & truth_s).sum() / truth_s.sum())
    return row


def refiner_table(ctx: BenchmarkContext, refiners: dict, count: int, per_scan: int) -> list[dict]:
    """One row per condition and residual angle: every refiner's template precision and
    recall, outliers removed and real source points kept (``refiners``: name -> object
    with ``predict_masks``)."""
    rows = []
    for set_name, pairs in _conditions(ctx, count, per_scan).items():
        for angle in RESIDUALS_DEG:
            key = {"set": set_name, "residual_deg": angle}
            rows.append(ctx.row(key, refiner_row, pairs, angle, ctx.seed, refiners))
    return rows


def refine_masks(ctx: BenchmarkContext) -> ExperimentResult:
    """The learned refinement mask against the nearest-neighbour rule, at fixed residuals."""
    from masknet.models.refine import RefineMaskNet

    refiners = {"rule": NearestNeighbourMasks(), "learned": RefineMaskNet.pretrained()}
    count = QUICK_MODELNET_PAIRS if ctx.quick else min(ctx.pairs, 300)
    per_scan = 1 if ctx.quick else 15
    rows = refiner_table(ctx, refiners, count, per_scan)
    summary = (
        f"The same pairs as masks-per-round ({count} per ModelNet40 set, "
        + (f"{QUICK_SCAN_PAIRS} scan pairs), " if ctx.quick else f"{per_scan} per scan), ")
        + "plus sensor-like ModelNet40 views (sampled apart from their 512-point templates, "
        "density falling off with the distance to the viewpoint, noise 0.005); each source moved onto its template by the true pose, then "
        "turned by the residual about its centroid. Template masks: top-k with k = the source "
        "points kept. Precision and recall of the template mask; outliers_removed: share of "
        "outlier source points rejected; real_kept: share of real source points kept."
    )
    return ExperimentResult(rows, summary)

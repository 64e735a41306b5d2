"""How precise the refinement mask can be on the scan pairs of "Masks per round".

    python scripts/mask_precision_ceiling.py --out docs/results/mask_precision_ceiling.json

For each pair of the two scan sets of ``masknet benchmark masks-per-round`` (15 per evaluation
scan, seed 0; the source copied from the template's points or re-sampled), the shipped
refinement network's template scores are taken at two poses: the one that
``register(template, source, iterations=3)`` returns, and the ground truth. The template mask
is the scores at or above a threshold (``register`` uses 0.9); for each threshold this prints
the mean precision and recall against the ground-truth mask. The last rows are a geometric
rule at the ground truth, for reference: the template points within f median template
spacings of the moved source. Two more rows at the truth, same threshold: the scores
averaged over each template point's SMOOTHING nearest template points (a spatially
coherent mask), and an *oracle* that keeps as many points as the network's mask, ranked by
the share of their ORACLE_NEIGHBOURS nearest template points that truly are inliers (their
own label unseen): what knowing the labels around a point buys. The scan folder is ``$MASKNET_SCANS`` (default
../shared/data/scans).

    python scripts/mask_precision_ceiling.py --validation ../shared/data/scans_train \
        --out docs/results/mask_threshold_validation.json

measures the same on the training scans the refinement network held out for validation
(its record names them): the set on which ``register``'s threshold is chosen, the lowest
of the thresholds whose precision at the returned pose is at least 0.95 on both sets.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
import torch

from masknet import register
from masknet.cli import run_script
from masknet.evaluation.registration import pair_arrays
from masknet.experiments.rounds import scan_eval_set
from masknet.geometry.clouds import median_spacing
from masknet.geometry.knn import cloud_tree
from masknet.geometry.se3 import transform_points
from masknet.io import write_text_atomic
from masknet.models.refine import RefineMaskNet
from masknet.models.weights import shipped_weights_path
from masknet.registration.stages.refinement import TEMPLATE_THRESHOLD

THRESHOLDS = (0.5, 0.8, 0.9, 0.925, 0.95, 0.97, 0.98)
SPACINGS = (1.0, 1.5, 2.0, 3.0)
SETS = ("scans, shared points", "scans, re-sampled")
REGISTER_THRESHOLD = TEMPLATE_THRESHOLD  # the per-scan figures are at register's threshold
SMOOTHING = 17  # the point and its 16 nearest template points
ORACLE_NEIGHBOURS = 8


def _precision_recall(predicted: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    tp = int((predicted & truth).sum())
    return tp / max(int(predicted.sum()), 1), tp / max(int(truth.sum()), 1)


def scan_set(
    shared: bool, refiner: RefineMaskNet, folder: Path | None = None, names: list | None = None
) -> dict:
    """Mean (precision, recall) per threshold at the returned pose and at the truth, and
    of the geometric rule at the truth, over one scan set (``folder`` and ``names`` as
    :func:`scan_eval_set`)."""
    pairs, scans = scan_eval_set(15, shared, seed=0, folder=folder, names=names)
    templates, sources, truths = pair_arrays(pairs)
    masks = pairs.mask.numpy()
    rows: dict[str, list] = {"returned": [], "truth": [], "rule": [], "smoothed": [], "oracle": []}
    per_scan: dict[str, list] = {}
    for i in range(len(truths)):
        template = templates[i].astype(np.float64)
        source = sources[i].astype(np.float64)
        result = register(template, source, iterations=3)
        for name, pose in (("returned", result.transform), ("truth", truths[i])):
            moved = transform_points(np.asarray(pose, np.float64), source)
            scores = refiner.predict(template.astype(np.float32), moved.astype(np.float32))[0]
            rows[name].append([_precision_recall(scores >= t, masks[i]) for t in THRESHOLDS])
            if name == "truth":
                kept = scores >= REGISTER_THRESHOLD
                at = _precision_recall(kept, masks[i])
                per_scan.setdefault(scans[i], []).append(at)
                near = cloud_tree(template).query(template, k=SMOOTHING)[1].astype(np.int64)
                smoothed = scores[near].mean(1) >= REGISTER_THRESHOLD
                rows["smoothed"].append(_precision_recall(smoothed, masks[i]))
                share = masks[i][near[:, 1 : ORACLE_NEIGHBOURS + 1]].mean(1) + 1e-3 * scores
                oracle = np.zeros_like(kept)
                oracle[np.argsort(-share, kind="stable")[: int(kept.sum())]] = True
                rows["oracle"].append(_precision_recall(oracle, masks[i]))
        moved = transform_points(np.asarray(truths[i], np.float64), source)
        distance = cloud_tree(moved).query(template, k=1)[0]
        spacing = median_spacing(template)
        rows["rule"].append(
            [_precision_recall(distance <= f * spacing, masks[i]) for f in SPACINGS]
        )
    return {name: np.asarray(values).mean(0).tolist() for name, values in rows.items()} | {
        "pairs": len(truths),
        "per_scan_at_truth": {k: np.asarray(v).mean(0).tolist() for k, v in per_scan.items()},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, help="also write the figures here (JSON)")
    parser.add_argument(
        "--validation",
        type=Path,
        metavar="SCANS_TRAIN",
        help="measure on the refiner's validation scans in this training-scan folder",
    )
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    refiner = RefineMaskNet.pretrained()
    names = None
    if args.validation:
        record = json.loads(shipped_weights_path("refinemask_scans.json").read_text())
        names = record["training"]["task"]["val_scans"]
    tic = time.perf_counter()
    out: dict = {
        "machine": f"{platform.machine()}, {args.threads} threads, torch {torch.__version__}",
        "thresholds": THRESHOLDS,
        "rule_spacings": SPACINGS,
        "scans": names or "evaluation scans",
    }
    for shared, name in ((True, "scans, shared points"), (False, "scans, re-sampled")):
        out[name] = scan_set(shared, refiner, args.validation, names)
    out["seconds"] = time.perf_counter() - tic
    print("| set | mask | at the pose | precision | recall |")
    print("|---|---|---|---|---|")
    for name in SETS:
        figures = out[name]
        for pose in ("returned", "truth"):
            for t, (p, r) in zip(THRESHOLDS, figures[pose], strict=True):
                print(f"| {name} | scores >= {t} | {pose} | {p:.3f} | {r:.3f} |")
        for f, (p, r) in zip(SPACINGS, figures["rule"], strict=True):
            print(f"| {name} | within {f} spacings | truth | {p:.3f} | {r:.3f} |")
        p, r = figures["smoothed"]
        print(
            f"| {name} | scores over {SMOOTHING} points >= {REGISTER_THRESHOLD} | truth | {p:.3f} | {r:.3f} |"
        )
        p, r = figures["oracle"]
        print(f"| {name} | oracle, as many points | truth | {p:.3f} | {r:.3f} |")
    print(f"\nPer scan at the truth, scores >= {REGISTER_THRESHOLD}:\n")
    print("| scan | " + " | ".join(f"{name}: precision / recall" for name in SETS) + " |")
    print("|---|" + "---|" * len(SETS))
    for scan in out[SETS[0]]["per_scan_at_truth"]:
        cells = [out[name]["per_scan_at_truth"].get(scan, [np.nan, np.nan]) for name in SETS]
        print(f"| {scan} | " + " | ".join(f"{p:.3f} / {r:.3f}" for p, r in cells) + " |")
    precise = [
        t
        for i, t in enumerate(THRESHOLDS)
        if all(out[name]["returned"][i][0] >= 0.95 for name in SETS)
    ]
    out["lowest_threshold_at_0.95"] = precise[0] if precise else None
    print(f"\nlowest threshold with precision >= 0.95 on both: {out['lowest_threshold_at_0.95']}")
    print(f"{out['seconds'] / 60:.1f} min, {out['machine']}")
    if args.out:
        write_text_atomic(args.out, json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    run_script(main)

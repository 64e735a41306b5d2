"""The refined loop, round by round, on the 3DMatch fragment pair with its ground truth.

    python scripts/rounds_on_real_pair.py --scans ../shared/data/scans --out docs/results/rounds_3dmatch.json

``register(template, source, iterations=K)`` with the default method: round 1 is the default
pipeline's answer, rounds >= 2 mask both clouds with the refinement network at the pose
reached and run ICP on the masked points. For each round this prints the rotation and
translation error against the ground truth, Open3D's fitness and inlier RMSE at 1.5 template
spacings, and the template mask's precision and recall against the overlap the ground truth
gives (template points within 1.5 spacings of the source moved by the true pose), in metres
and again with the clouds in millimetres.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
import torch

from masknet import evaluate_registration, register
from masknet.cli import run_script
from masknet.evaluation.registration import pose_errors
from masknet.experiments.scans import THREEDMATCH_FILES, load_pair
from masknet.geometry.clouds import median_spacing
from masknet.geometry.knn import cloud_tree
from masknet.geometry.se3 import transform_points
from masknet.io import write_text_atomic


def per_round(template: np.ndarray, source: np.ndarray, truth: np.ndarray, rounds: int) -> list:
    """One row per round of ``register(template, source, iterations=rounds)``; masks and
    errors of round r come from the call with r rounds (its masks are those of its pose)."""
    spacing = median_spacing(template)
    cut = 1.5 * spacing
    overlap = cloud_tree(transform_points(truth, source)).query(template, k=1)[0] <= cut
    rows = []
    for r in range(1, rounds + 1):
        tic = time.perf_counter()
        result = register(template, source, iterations=r)
        seconds = time.perf_counter() - tic
        rot, trans = pose_errors(result.transform[None], truth[None])
        fit = evaluate_registration(
            template=template,
            source=source,
            transform=result.transform,
            max_correspondence_distance=cut,
        )
        mask = result.mask
        tp = int((mask & overlap).sum()) if mask is not None else 0
        rows.append(
            {
                "round": r,
                "path": str(result.info["path"]),
                "rot_deg": float(rot[0]),
                "trans": float(trans[0]),
                "fitness": float(fit.fitness),
                "inlier_rmse": float(fit.inlier_rmse),
                "precision": tp / max(int(mask.sum()), 1) if mask is not None else None,
                "recall": tp / max(int(overlap.sum()), 1) if mask is not None else None,
                "source_kept": (
                    float(result.source_mask.mean()) if result.source_mask is not None else None
                ),
                "seconds": seconds,
            }
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=Path, default=Path("../shared/data/scans"))
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, help="also write the rows here (JSON)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    template, source, truth = load_pair(args.scans, *THREEDMATCH_FILES)
    units = {"m": 1.0, "mm": 1000.0}
    out = {
        "machine": f"{platform.machine()}, {args.threads} threads, torch {torch.__version__}",
        "template_points": len(template),
        "source_points": len(source),
    }
    for unit, scale in units.items():
        scaled = truth.copy()
        scaled[:3, 3] *= scale
        rows = per_round(template * scale, source * scale, scaled, args.rounds)
        out[unit] = rows
        print(f"\nclouds in {unit} ({len(template):,} and {len(source):,} points)")
        print(
            "| round | path | rotation error | translation error (cm) | fitness | "
            "inlier RMSE (cm) | mask precision | mask recall | source kept | time (s) |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|")
        for row in rows:
            cm = 100.0 / scale
            print(
                f"| {row['round']} | {row['path']} | {row['rot_deg']:.2f}° | "
                f"{row['trans'] * cm:.1f} | {row['fitness']:.3f} | "
                f"{row['inlier_rmse'] * cm:.2f} | {_f(row['precision'])} | "
                f"{_f(row['recall'])} | {_f(row['source_kept'])} | {row['seconds']:.2f} |"
            )
    if args.out:
        write_text_atomic(args.out, json.dumps(out, indent=1) + "\n")


def _f(value: float | None) -> str:
    return "" if value is None else f"{value:.3f}"


if __name__ == "__main__":
    run_script(main)

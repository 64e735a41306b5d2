"""Outliers in the source: X, Mask-X (the paper's MaskNet) and two-sided Mask-X, and the
two-sided network as a learned denoiser beside the distance rule and Open3D's filter.

    python scripts/two_sided_benchmark.py --data $MASKNET_DATA --pairs 1000 --ratios 0 --out docs/results/two_sided_clean.json
    python scripts/two_sided_benchmark.py --data $MASKNET_DATA --pairs 200 --ratios 0,0.1,0.2 --out docs/results/two_sided.json
    python scripts/two_sided_benchmark.py --data $MASKNET_DATA --decompose --pairs 1000 --ratios 0 --out docs/results/two_sided_decomposed.json

ModelNet40 test shapes, the paper's protocol (70% views, rotations up to 45 degrees),
uniform outliers in the source's bounding box (:class:`masknet.data.PairConfig`). The
denoisers run on the same pairs as they are (misaligned) and on aligned ones (no motion).

``--decompose`` splits the two-sided network's difference from the paper's mask, after one
round, into its two parts: the template mask (computed without the rejected source points)
and the source points it drops.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

from masknet import register
from masknet.cli import run_script
from masknet.data import PairConfig, load_modelnet40, make_test_pairs
from masknet.denoising import denoise, open3d_statistical_outlier_removal
from masknet.evaluation.registration import pair_arrays, paired_difference, pose_errors
from masknet.io import write_text_atomic
from masknet.metrics import outlier_removal_metrics
from masknet.models import MaskNet
from masknet.models.two_sided import TwoSidedMaskNet


def denoise_rows(model: TwoSidedMaskNet, points: np.ndarray, ratio: float, args) -> list[dict]:
    """Outlier removal by the learned mask, the template-distance rule and Open3D's
    statistical filter, on misaligned (<= 45 degrees) and on aligned pairs."""
    out = []
    for motion, config in [
        ("misaligned", PairConfig(outlier_ratio=ratio)),
        ("aligned", PairConfig(outlier_ratio=ratio, max_angle_deg=0, max_translation=0)),
    ]:
        pairs = make_test_pairs(points, args.pairs, config, args.seed)
        tpl, src, _ = pair_arrays(pairs)
        real = pairs.source_mask.numpy()
        kept = {
            "two-sided MaskNet (source mask >= 0.5)": model.predict_masks(tpl, src)[1],
            "template distance (3x spacing)": np.stack(
                [denoise(t, s).mask for t, s in zip(tpl, src, strict=True)]
            ),
            "Open3D statistical (20 nn, 2 std)": np.stack(
                [open3d_statistical_outlier_removal(s) for s in src]
            ),
        }
        for name, mask in kept.items():
            row = {"outliers": ratio, "pairs": motion, "method": name}
            out.append(row | outlier_removal_metrics(mask, real))
            print(out[-1], flush=True)
    return out


class GivenMasks:
    """A mask network, to ``register``, whose masks were computed beforehand: the
    template mask (P, N) and the source points kept (P, M), or None for every one."""

    def __init__(self, template_mask: np.ndarray, source_keep: np.ndarray | None) -> None:
        self.masks = (template_mask, source_keep)

    def predict_masks(self, template, source, **options):
        return self.masks


def one_round(tpl, src, method, template_mask, source_keep) -> np.ndarray:
    """(P, 4, 4): one round of Mask-X with the given masks, run by ``register`` itself."""
    result = register(
        tpl,
        src,
        method=method,
        model=GivenMasks(template_mask, source_keep),
        max_points=max(tpl.shape[1], src.shape[1]),  # the masks are for the clouds as given
    )
    return result.transform


def decompose_rows(masks: dict, points: np.ndarray, ratio: float, args) -> list[dict]:
    """Paired differences from the paper's mask after one round, with each of the two
    sided network's masks swapped in alone."""
    pairs = make_test_pairs(points, args.pairs, PairConfig(outlier_ratio=ratio), args.seed)
    tpl, src, truth = pair_arrays(pairs)
    real = pairs.source_mask.numpy()
    paper = masks["Mask-X"].predict_mask(tpl, src)
    two_template, keep = masks["two-sided Mask-X"].predict_masks(tpl, src)
    rejected = {
        "real_points_kept": float(keep[real].mean()),
        "pairs_keeping_every_real_point": float((keep | ~real).all(1).mean()),
    }
    print(rejected, flush=True)
    variants = {
        "Mask-X (paper's template mask, every source point)": (paper, None),
        "two-sided Mask-X (both masks)": (two_template, keep),
        "two-sided template mask, every source point": (two_template, None),
        "paper's template mask, two-sided source mask": (paper, keep),
    }
    rows = []
    for method in args.methods.split(","):
        errors = {}
        for name, (template_mask, source_keep) in variants.items():
            estimate = one_round(tpl, src, method, template_mask, source_keep)
            errors[name] = pose_errors(estimate, truth)[0]
        base = next(iter(errors.values()))
        for name, rot in errors.items():
            rows.append(
                {"outliers": ratio, "method": method, "variant": name}
                | {"mean_rot": float(rot.mean()), "median_rot": float(np.median(rot))}
                | paired_difference(rot, base, "paired_diff_vs_mask_x")
                | rejected
            )
            print(rows[-1], flush=True)
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True)
    p.add_argument("--pairs", type=int, default=200)
    p.add_argument("--ratios", default="0,0.05,0.1,0.2")
    p.add_argument("--methods", default="icp,pointnetlk")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--iterations", default="1,3", help="rounds of mask -> register to run")
    p.add_argument("--decompose", action="store_true", help="split the one-round difference")
    p.add_argument(
        "--two-sided-weights", help="a two-sided weights file (default: the shipped one)"
    )
    p.add_argument("--out")
    args = p.parse_args()
    torch.set_num_threads(2)
    points = load_modelnet40(args.data, "test").points
    masks = {
        "X": None,
        "Mask-X": MaskNet.pretrained(),
        "two-sided Mask-X": (
            TwoSidedMaskNet.from_file(args.two_sided_weights)
            if args.two_sided_weights
            else TwoSidedMaskNet.pretrained()
        ),
    }
    if args.decompose:
        ratios = [float(r) for r in args.ratios.split(",")]
        rows = [row for r in ratios for row in decompose_rows(masks, points, r, args)]
        if args.out:
            write_text_atomic(args.out, json.dumps({"decomposed": rows}, indent=1))
        return
    rows, denoising = [], []
    for ratio in [float(r) for r in args.ratios.split(",")]:
        pairs = make_test_pairs(points, args.pairs, PairConfig(outlier_ratio=ratio), args.seed)
        tpl, src, truth = pair_arrays(pairs)
        if ratio > 0:
            denoising += denoise_rows(masks["two-sided Mask-X"], points, ratio, args)
        for method, rounds in [
            (m, int(r)) for m in args.methods.split(",") for r in args.iterations.split(",")
        ]:
            errors = {}
            for name, model in masks.items():
                tic = time.perf_counter()
                result = register(
                    tpl,
                    src,
                    method=method,
                    use_mask=model is not None,
                    model=model,
                    iterations=rounds,
                    refine_masks="network",  # the same mask in every round, as published
                )
                rot, trans = pose_errors(result.transform, truth)
                errors[name] = rot
                rows.append(
                    {
                        "outliers": ratio,
                        "method": method,
                        "iterations": rounds,
                        "variant": name,
                        "mean_rot": float(rot.mean()),
                        "median_rot": float(np.median(rot)),
                        "p90_rot": float(np.percentile(rot, 90)),
                        "mean_trans": float(trans.mean()),
                        "seconds": time.perf_counter() - tic,
                    }
                )
                print(rows[-1], flush=True)
            # Paired over the same pairs: two-sided minus the paper's mask, and its standard
            # error, so that a small difference can be told from the pairs' own spread.
            rows[-1] |= paired_difference(
                errors["two-sided Mask-X"], errors["Mask-X"], "paired_diff_vs_mask_x"
            )
            print(
                f"two-sided - Mask-X: {rows[-1]['paired_diff_vs_mask_x']:+.3f} "
                f"+- {rows[-1]['paired_se']:.3f}"
            )
    if args.out:
        write_text_atomic(
            args.out, json.dumps({"registration": rows, "denoising": denoising}, indent=1)
        )


if __name__ == "__main__":
    run_script(main)

"""Where Mask-PointNetLK's error comes from: the same PointNetLK weights on the same pairs
with no mask, MaskNet's mask, the true mask, and on full clouds at the same rotations.

    python scripts/pointnetlk_diagnosis.py --pairs 1000 --weights shipped runs/x/best.safetensors

ModelNet40 test pairs of the paper's protocol (70% views, rotations <= 45 degrees), seed 0;
PointNetLK's one call, 10 iterations, the template points given as its valid points. The
mask is the shipped MaskNet's top-k (k = M). Rows by the mask's precision show how the
error grows with the mask's mistakes.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from masknet.cli import run_script


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=1000, help="test pairs (default 1000)")
    parser.add_argument(
        "--weights",
        nargs="+",
        default=["shipped"],
        help="PointNetLK weights: 'shipped' or .safetensors files (default shipped)",
    )
    parser.add_argument("--data", help="ModelNet40 (default: $MASKNET_DATA)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", help="write the figures to this JSON file")
    args = parser.parse_args()

    from masknet import MaskNet
    from masknet.data import PairConfig, load_modelnet40, make_test_pairs
    from masknet.geometry import rotation_error_deg
    from masknet.models import PointNetLK

    torch.set_num_threads(args.threads)
    shapes = load_modelnet40(args.data, "test").points
    pairs = make_test_pairs(shapes, args.pairs, PairConfig(), seed=0)
    full = make_test_pairs(shapes, args.pairs, PairConfig(keep_ratio=1.0), seed=0)
    masknet = MaskNet.pretrained()
    predicted = torch.as_tensor(
        masknet.predict_mask(pairs.template.numpy(), pairs.source.numpy(), precision="fp32")
    )
    precision = ((predicted & pairs.mask).sum(1) / predicted.sum(1)).double()
    cases = {
        "full clouds (no part missing)": (full, None, 10),
        "partial, no mask (PointNetLK)": (pairs, None, 10),
        "MaskNet's mask (Mask-PointNetLK)": (pairs, predicted, 10),
        "the true mask": (pairs, pairs.mask, 10),
        "MaskNet's mask, 30 iterations": (pairs, predicted, 30),
    }
    results: dict = {"pairs": args.pairs, "mask_precision": float(precision.mean())}
    print(f"{args.pairs} pairs; MaskNet's top-k precision {precision.mean():.3f}\n")
    print("| weights | case | rot mean | rot median | rot p90 |")
    print("|---|---|---|---|---|")
    for name in args.weights:
        network = PointNetLK.pretrained() if name == "shipped" else PointNetLK.from_file(name)
        network.eval()
        errors = {}
        for case, (batch, valid, iterations) in cases.items():
            with torch.no_grad():
                solution = network(
                    batch.template, batch.source, template_valid=valid, max_iterations=iterations
                )
            error = rotation_error_deg(
                solution.transform[:, :3, :3].double(), batch.transform[:, :3, :3].double()
            ).numpy()
            errors[case] = error
            print(
                f"| {name} | {case} | {error.mean():.2f} | {np.median(error):.2f} | "
                f"{np.quantile(error, 0.9):.2f} |"
            )
        masked = errors["MaskNet's mask (Mask-PointNetLK)"]
        buckets = {}
        for lo, hi in [(0.0, 0.85), (0.85, 0.9), (0.9, 0.95), (0.95, 1.01)]:
            rows = ((precision >= lo) & (precision < hi)).numpy()
            if rows.any():
                buckets[f"{lo:.2f}-{min(hi, 1):.2f}"] = (
                    int(rows.sum()),
                    float(masked[rows].mean()),
                )
        print(f"\n{name}: Mask-PointNetLK's mean error by the mask's precision:")
        for key, (count, mean) in buckets.items():
            print(f"  precision {key}: {count} pairs, {mean:.2f} deg")
        print()
        results[name] = {
            "cases": {
                case: {"mean": float(e.mean()), "median": float(np.median(e))}
                for case, e in errors.items()
            },
            "by_precision": buckets,
        }
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    run_script(main)

"""Paired comparison of two MaskNet weight files on the same seeded ModelNet40 test pairs.

    python scripts/compare_masknets.py OLD.safetensors NEW.safetensors --data PATH

Prints each model's mean top-k (k = M) precision with its standard error over the pairs,
and the mean per-pair difference NEW - OLD with the standard error of that difference.
Pairing removes the pairs' own difficulty from the comparison, so a difference far
smaller than either mean's standard error can still be measured.
"""

from __future__ import annotations

import argparse

import numpy as np

from masknet.cli import run_script
from masknet.data import load_modelnet40
from masknet.evaluation.evaluate import evaluate_masknet
from masknet.models import MaskNet


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old")
    parser.add_argument("new")
    parser.add_argument("--data", help="ModelNet40 folder or .npz (default: $MASKNET_DATA)")
    parser.add_argument("--pairs", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    points = load_modelnet40(args.data, "test").points
    scores = {}
    for name in ("old", "new"):
        path = getattr(args, name)
        ev = evaluate_masknet(
            MaskNet.from_file(path), points, args.pairs, args.seed, progress=False
        )
        scores[name] = ev.topk_precision
        mean, se = scores[name].mean(), ev.topk_precision_stderr
        print(f"{name}: {path}: top-k precision {mean:.4f} +- {se:.4f}")
    diff = scores["new"] - scores["old"]
    se = diff.std(ddof=1) / np.sqrt(len(diff))
    print(f"new - old, paired over {len(diff)} pairs: {diff.mean():+.4f} +- {se:.4f}")


if __name__ == "__main__":
    run_script(main)

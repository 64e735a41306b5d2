"""Latency of MaskNet's forward paths, measured in one run so ratios are fair.

    python -m masknet.evaluation.timing --batch 1 --threads 2 --repeats 100

Each variant gets warm-up calls, then the median of ``repeats`` timed calls on
the same inputs. The reference is :class:`~masknet.models.reference.PaperMaskNet`.
With ``--data``, the bf16 path's top-k mask agreement with fp32 is also measured
on ``--agreement-pairs`` seeded ModelNet40 test pairs.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from collections.abc import Callable

import torch

from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.evaluation.evaluate import mask_agreement
from masknet.io import write_text_atomic
from masknet.models import MaskNet, select_mask
from masknet.models.reference import PaperMaskNet

__all__ = ["median_ms", "time_masknet_variants"]


def median_ms(fn: Callable[[], object], repeats: int = 50, warmup: int = 5) -> float:
    """Median wall time of ``fn()`` in milliseconds, after ``warmup`` untimed calls."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times)


def time_masknet_variants(model: MaskNet, batch: int = 1, repeats: int = 50, seed: int = 0) -> dict:
    """Time reference, split-head and fused paths on seeded sample pairs (N = 1024, M = 717).

    Returns ms per call for each variant, the speed-up against the reference, and
    the top-k mask agreement of each variant with the reference on those pairs.
    """
    points = load_modelnet40(bundled_sample_path(), "test").points
    pairs = make_test_pairs(points, batch, PairConfig(), seed)
    t, s = pairs.template, pairs.source
    reference = PaperMaskNet(model)
    variants: dict[str, Callable[[], torch.Tensor]] = {
        "reference (Conv1d, concat, fp32)": lambda: reference(t, s),
        "split head, fp32": lambda: model(t, s),
        "fused (split + folded BN), fp32": lambda: model.fused("fp32")(t, s),
        "fused, bf16": lambda: model.fused("bf16")(t, s),
    }
    results = {}
    with torch.inference_mode():
        ref_mask = select_mask(variants["reference (Conv1d, concat, fp32)"](), k=s.shape[1])
        for name, fn in variants.items():
            ms = median_ms(fn, repeats=repeats)
            agreement = (select_mask(fn().float(), k=s.shape[1]) == ref_mask).float().mean().item()
            results[name] = {"ms": ms, "topk_agreement": agreement}
    base = results["reference (Conv1d, concat, fp32)"]["ms"]
    for row in results.values():
        row["speedup"] = base / row["ms"]
    return {
        "batch": batch,
        "n": t.shape[1],
        "m": s.shape[1],
        "threads": torch.get_num_threads(),
        "machine": f"{platform.machine()}, torch {torch.__version__}",
        "variants": results,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--json")
    parser.add_argument(
        "--data", help="ModelNet40 data: also measure bf16 mask agreement on its test split"
    )
    parser.add_argument("--agreement-pairs", type=int, default=1000)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    result = time_masknet_variants(MaskNet.pretrained(), args.batch, args.repeats)
    print(f"batch {result['batch']}, N={result['n']}, M={result['m']}, {result['threads']} threads")
    print(f"{'variant':36s}{'ms':>9s}{'speed-up':>10s}{'top-k agree':>13s}")
    for name, row in result["variants"].items():
        print(f"{name:36s}{row['ms']:9.2f}{row['speedup']:9.2f}x{row['topk_agreement']:13.4f}")
    if args.data:
        test = load_modelnet40(args.data, "test").points
        agreement = mask_agreement(MaskNet.pretrained(), test, "bf16", args.agreement_pairs)
        result["bf16_agreement"] = agreement | {"pairs": args.agreement_pairs}
        print(
            f"bf16 vs fp32 on {args.agreement_pairs} ModelNet40 test pairs: "
            + ", ".join(f"{k} {v:.4f}" for k, v in agreement.items())
        )
    if args.json:
        write_text_atomic(args.json, json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()

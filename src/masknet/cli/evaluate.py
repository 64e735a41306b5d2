"""``masknet evaluate``: mask metrics on seeded ModelNet40 test pairs."""

from __future__ import annotations

import argparse
import json

from masknet.cli._common import (
    add_model_options,
    add_pair_options,
    load_model,
    pair_config,
    positive_int,
    seed,
)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``evaluate`` to the ``masknet`` subparsers."""
    p = subparsers.add_parser(
        "evaluate", help="mask precision/recall/F1/IoU on seeded ModelNet40 test pairs"
    )
    p.add_argument("--data", help="ModelNet40 folder or .npz (default: $MASKNET_DATA)")
    p.add_argument("--pairs", type=positive_int, default=1000)
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument("--json", help="also write the results to this JSON file")
    p.add_argument(
        "--realign-rounds",
        type=positive_int,
        default=1,
        metavar="R",
        help="also report the top-k mask predicted in round R of mask -> Mask-ICP (30 "
        "iterations) -> move the source: MaskNet inside the iterative pipeline",
    )
    add_model_options(p)
    add_pair_options(p)


def run(args: argparse.Namespace) -> None:
    """Print the metrics table (and write it as JSON with ``--json``)."""
    from masknet.data import load_modelnet40
    from masknet.evaluation.evaluate import evaluate_masknet, format_table
    from masknet.io import write_text_atomic

    model = load_model(args)
    data = load_modelnet40(args.data, "test").subset(args.categories)
    result = evaluate_masknet(
        model,
        data.points,
        args.pairs,
        args.seed,
        pair_config(args),
        precision=args.inference_precision,
        realign_rounds=args.realign_rounds,
    )
    print(
        f"{args.pairs} pairs from {len(data)} test shapes ({args.categories} categories), seed {args.seed}"
    )
    print(format_table(result.rows))
    print(f"top-k precision: standard error of the mean {result.topk_precision_stderr:.4f}")
    print(f"inference: {result.ms_per_pair:.2f} ms/pair (batched, {args.inference_precision})")
    if args.json:
        out = result.to_dict() | {
            "categories": args.categories,
            "weights": args.weights or args.pretrained,
        }
        write_text_atomic(args.json, json.dumps(out, indent=2) + "\n")
        print(f"wrote {args.json}")

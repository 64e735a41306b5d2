"""``masknet evaluate``: mask metrics on seeded ModelNet40 test pairs, or on pairs cut from scans."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from masknet.cli import _scans
from masknet.cli._common import (
    add_model_options,
    add_output_option,
    add_pair_options,
    load_model,
    pair_config,
    positive_int,
    seed,
)
from masknet.cli._outputs import check_outputs
from masknet.errors import MaskNetError


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``evaluate`` to the ``masknet`` subparsers."""
    p = subparsers.add_parser(
        "evaluate",
        help="measure mask precision on test pairs or real scans",
        description="mask precision/recall/F1/IoU on seeded ModelNet40 test pairs, or (--scans) on "
        "pairs cut from real scans, with ICP against Mask-ICP",
    )
    p.add_argument("--data", help="ModelNet40 folder or .npz (default: $MASKNET_DATA)")
    p.add_argument("--pairs", type=positive_int, default=1000, help="test pairs (default 1000)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the test pairs (default 0)")
    add_output_option(p, help="also write the results to this JSON file", old="--json")
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
    _scans.add_evaluate_options(p)


def run(args: argparse.Namespace) -> None:
    """Print the metrics table (and write it as JSON with ``-o/--output``)."""
    from masknet.data import load_modelnet40
    from masknet.evaluation.evaluate import evaluate_masknet, format_table
    from masknet.io import write_text_atomic

    if args.output:  # refused now, not after the evaluation: an input, a folder, no way in
        inputs = filter(None, (args.data, args.weights))
        check_outputs([Path(args.output)], (".json",), inputs)
    model = load_model(args)
    if args.scans:
        _run_scans(args, model)
        return
    data = load_modelnet40(args.data, "test").subset(args.categories)
    result = evaluate_masknet(
        model,
        data.points,
        args.pairs,
        args.seed,
        pair_config(args),
        precision=args.precision,
        realign_rounds=args.realign_rounds,
    )
    print(
        f"{args.pairs} pairs from {len(data)} test shapes ({args.categories} categories), seed {args.seed}"
    )
    print(format_table(result.rows))
    print(f"top-k precision: standard error of the mean {result.topk_precision_stderr:.4f}")
    print(f"inference: {result.ms_per_pair:.2f} ms/pair (batched, {args.precision})")
    if args.output:
        out = result.to_dict() | {
            "categories": args.categories,
            "weights": args.weights,
        }
        write_text_atomic(args.output, json.dumps(out, indent=2) + "\n")
        print(f"wrote {args.output}")


def _run_scans(args: argparse.Namespace, model) -> None:
    """``--scans``: masks and registration on pairs cut from every scan in the folder."""
    from masknet.evaluation.evaluate import format_table
    from masknet.evaluation.scans import SCAN_PIPELINES, evaluate_scans
    from masknet.io import write_text_atomic

    if args.scan_noise < 0:
        raise MaskNetError(f"--scan-noise must be >= 0, got {args.scan_noise}")
    scans = _scans.read_scans(args.scans, args.scan_names)
    view = _scans.view_config(args, args.scan_noise, random_noise=False)
    result = evaluate_scans(
        model,
        scans,
        args.pairs_per_scan,
        args.seed,
        view,
        precision=args.precision,
        pipelines=None if args.no_registration else SCAN_PIPELINES,
    )
    total = args.pairs_per_scan * len(scans)
    print(
        f"{total} pairs from {len(scans)} scans in {args.scans} ({args.pairs_per_scan} each), "
        f"seed {args.seed}; {view.template_points} template points, noise {view.noise_sigma:g} "
        "of the crop radius"
    )
    print(format_table(result.mask.rows))
    print(f"top-k precision: standard error of the mean {result.mask.topk_precision_stderr:.4f}")
    width = max(len(name) for name in result.per_scan) + 2
    print("\n" + "scan".ljust(width) + "top-k precision".rjust(16))
    for name, value in result.per_scan.items():
        print(name.ljust(width) + f"{value:16.4f}")
    if result.registration:
        print("\nregistration  rotation error (deg) mean / median, translation (crop radii), time")
        for name, row in result.registration.items():
            print(
                f"{name:<22}{row['rot_mean']:8.2f} {row['rot_median']:8.2f} "
                f"  {row['trans_mean']:.4f}   {row['ms_per_pair']:.1f} ms"
            )
    if args.output:
        out = result.to_dict() | {"weights": args.weights}
        write_text_atomic(args.output, json.dumps(out, indent=2) + "\n")
        print(f"wrote {args.output}")

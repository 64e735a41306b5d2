"""``masknet demo``: the shipped model on the bundled sample, metrics and a picture."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from masknet._extras import PICTURES, require
from masknet.cli._common import (
    add_model_options,
    add_output_option,
    load_model,
    positive_int,
    seed,
)
from masknet.cli._outputs import refuse_inputs


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``demo`` to the ``masknet`` subparsers."""
    p = subparsers.add_parser(
        "demo",
        help="run the shipped model on the bundled sample",
        description="run the shipped model on the bundled sample: metrics and a picture",
    )
    add_output_option(
        p,
        help="folder for the picture and metrics (default masknet_demo)",
        old="--out",
        default="masknet_demo",
        metavar="OUTDIR",
    )
    p.add_argument(
        "--pairs", type=positive_int, default=240, help="pairs to evaluate (default 240)"
    )
    p.add_argument("--seed", type=seed, default=0, help="seed of the pairs (default 0)")
    add_model_options(p)


def run(args: argparse.Namespace) -> None:
    """Evaluate on the sample; write ``masknet_demo.png`` and ``metrics.json``."""
    require(*PICTURES)  # for the picture; refused now, not after the evaluation
    out = Path(args.output)
    refuse_inputs([out / "masknet_demo.png", out / "metrics.json"], filter(None, [args.weights]))
    import torch

    from masknet.data import bundled_sample_path, load_modelnet40
    from masknet.evaluation.evaluate import evaluate_masknet, format_table
    from masknet.io import write_text_atomic
    from masknet.models import select_mask
    from masknet.viz import plot_mask

    model = load_model(args)
    sample = load_modelnet40(bundled_sample_path(), "test")
    result = evaluate_masknet(
        model,
        sample.points,
        args.pairs,
        args.seed,
        precision=args.precision,
        progress=False,
        keep_outputs=True,
    )
    pairs = result.pairs_data
    print(
        f"MaskNet ({args.weights}) on the bundled sample: {args.pairs} seeded pairs "
        f"from {len(sample)} ModelNet40 test shapes, 30% missing, rotation <= 45 deg, translation <= 1"
    )
    print(format_table(result.rows))
    print(f"inference: {result.ms_per_pair:.2f} ms/pair (batched, {args.precision})")
    out = Path(args.output)
    predicted = select_mask(torch.from_numpy(result.scores[:1]), k=pairs.source.shape[1])[0].numpy()
    picture = plot_mask(
        pairs.template[0].numpy(),
        pairs.source[0].numpy(),
        predicted,
        out / "masknet_demo.png",
        truth=pairs.mask[0].numpy(),
        title="MaskNet: template inliers predicted from a partial source",
    )
    write_text_atomic(out / "metrics.json", json.dumps(result.to_dict(), indent=2) + "\n")
    print(f"wrote {picture} and {out / 'metrics.json'}")

"""``masknet mask``: which template points the source sees, written as points and a mask."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from masknet.cli._common import (
    add_cloud_arguments,
    add_file_options,
    add_model_options,
    finite_float,
    load_model,
    positive_int,
)
from masknet.cli._mask_outputs import mask_outputs, write_kept
from masknet.errors import MaskNetError


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``mask`` to the ``masknet`` subparsers."""
    p = subparsers.add_parser(
        "mask",
        help="mark the TEMPLATE points that SOURCE also sees",
        description="predict which TEMPLATE points SOURCE sees; write them and the mask",
    )
    add_cloud_arguments(p, source_help="partial cloud of the same object")
    p.add_argument(
        "-o",
        "--output",
        required=True,
        help="inlier template points (format from the extension); the mask goes to "
        "<stem>_mask.txt beside it, one 0/1 per template point",
    )
    sel = p.add_mutually_exclusive_group()
    sel.add_argument(
        "--k", type=positive_int, help="keep the k highest scores (default: k = source points)"
    )
    sel.add_argument(
        "--threshold", type=finite_float, help="keep scores >= this (the paper's epsilon)"
    )
    add_file_options(p)
    add_model_options(p)


def run(args: argparse.Namespace) -> None:
    """Predict the mask; write the inlier points and ``<stem>_mask.txt`` (and views)."""
    import numpy as np

    from masknet.io import read_points, read_points_with_rows

    if args.threshold is not None and not 0 <= args.threshold <= 1:
        raise MaskNetError(f"--threshold must be in [0, 1] (scores are), got {args.threshold}")
    paths = mask_outputs(args, inputs=[args.template, args.source])
    template, template_rows = read_points_with_rows(
        args.template, drop_nonfinite=args.drop_nonfinite
    )
    source = read_points(args.source, drop_nonfinite=args.drop_nonfinite)
    if args.k is None and args.threshold is None and len(source) >= len(template):
        # Top-k with k = source points would keep the whole template: most often the
        # clouds were given the other way round.
        print(
            f"masknet: warning: SOURCE has {len(source)} points and TEMPLATE {len(template)}, "
            "so top-k (k = source points) keeps every template point; TEMPLATE is the full "
            "cloud and SOURCE the partial one (or give --k or --threshold)",
            file=sys.stderr,
        )
    model = load_model(args)
    mask, scores = model.predict_mask_with_scores(
        template, source, k=args.k, threshold=args.threshold, precision=args.precision
    )
    layers = {"template": template, "source": source, "inliers": template[mask]}
    title = f"MaskNet inliers: {Path(args.template).name} seen by {Path(args.source).name}"
    written = write_kept(args, paths, args.template, template, template_rows, mask, layers, title)
    if args.threshold is not None:
        rule = f"threshold {args.threshold}"
    else:
        k = args.k if args.k is not None else len(source)
        rule = f"top-k, k={min(k, len(template))}"
    print(
        f"kept {int(mask.sum())} of {len(template)} template points ({rule}); "
        f"mean score {float(np.mean(scores)):.3f}"
    )
    print(f"wrote {', '.join(map(str, written))}")

"""``masknet denoise``: drop the points of a noisy scan that a clean template does not explain."""

from __future__ import annotations

import argparse
from pathlib import Path

from masknet.cli._common import (
    add_file_options,
    add_model_options,
    finite_float,
    load_model,
    load_weights,
)
from masknet.cli._mask_outputs import mask_outputs, write_kept
from masknet.errors import MaskNetError


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``denoise`` to the ``masknet`` subparsers."""
    p = subparsers.add_parser(
        "denoise",
        help="drop the points of a scan that TEMPLATE does not explain",
        description="remove the points of NOISY that TEMPLATE (a clean cloud of the same object) "
        "does not explain",
    )
    p.add_argument(
        "template",
        help="a clean cloud of the object: .ply .pcd .xyz .txt .csv .npy .bin; for --method "
        "distance aligned with NOISY (e.g. after register), for --method masknet in any pose "
        "within about 45 degrees",
    )
    p.add_argument("noisy", help="the scan with outliers, of the same object")
    p.add_argument(
        "-o",
        "--output",
        required=True,
        help="the kept points (format from the extension); <stem>_mask.txt beside it, "
        "one 0/1 per noisy point",
    )
    p.add_argument(
        "--method",
        choices=["distance", "masknet", "refined"],
        default="distance",
        help="distance (default): keep points near the template (aligned clouds); "
        "masknet: the two-sided MaskNet's source mask, no alignment needed (shipped "
        "masknet2_scans, or --weights from masknet train --model masknet2 or denoise); "
        "refined: the refinement mask, which sees both clouds in one frame (aligned clouds; "
        "shipped refinemask_scans, or --weights from masknet train --model refine)",
    )
    p.add_argument(
        "--threshold",
        type=finite_float,
        default=0.5,
        help="masknet, refined: keep points scoring >= this (default 0.5)",
    )
    p.add_argument(
        "--max-distance",
        type=finite_float,
        help="distance: the largest distance kept, in the clouds' units "
        "(default 3x the template's point spacing)",
    )
    add_file_options(p)
    add_model_options(
        p,
        default_weights="scans",
        kind="two-sided MaskNet (--method masknet) or refinement network (--method refined)",
    )


def run(args: argparse.Namespace) -> None:
    """Denoise; write the kept points and ``<stem>_mask.txt`` (and views)."""
    from masknet.denoising import denoise
    from masknet.io import read_points, read_points_with_rows

    if not 0 <= args.threshold <= 1:
        raise MaskNetError(f"--threshold must be in [0, 1], got {args.threshold}")
    paths = mask_outputs(args, inputs=[args.template, args.noisy])
    template = read_points(args.template, drop_nonfinite=args.drop_nonfinite)
    noisy, noisy_rows = read_points_with_rows(args.noisy, drop_nonfinite=args.drop_nonfinite)
    if args.method == "distance":
        result = denoise(template, noisy, method="distance", max_distance=args.max_distance)
        rule = f"distance <= {args.max_distance or '3x template spacing'}"
    else:
        if args.method == "refined":
            from masknet.models.refine import RefineMaskNet

            model = load_weights(RefineMaskNet, args.weights)
        else:
            model = load_model(args, two_sided=True)
        result = denoise(
            template,
            noisy,
            method=args.method,
            model=model,
            threshold=args.threshold,
            precision=args.precision,
        )
        rule = f"MaskNet score >= {args.threshold}"
    layers = {"template": template, "kept": result.points, "removed": noisy[~result.mask]}
    title = f"MaskNet denoising: {Path(args.noisy).name}"
    written = write_kept(args, paths, args.noisy, noisy, noisy_rows, result.mask, layers, title)
    removed = int((~result.mask).sum())
    dropped = int((~noisy_rows).sum())
    print(
        f"kept {int(result.mask.sum())} of {len(noisy)} points, removed {removed} "
        f"({100 * removed / len(noisy):.1f}%, {rule})"
        + (f"; {dropped} non-finite rows dropped before" if dropped else "")
    )
    print(f"wrote {', '.join(map(str, written))}")

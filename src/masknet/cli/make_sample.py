"""``masknet make-sample``: rebuild the bundled sample from the ModelNet40 test split."""

from __future__ import annotations

import argparse

from masknet.cli._common import (
    positive_int,
)
from masknet.cli._outputs import refuse_inputs


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``make-sample`` to the ``masknet`` subparsers."""
    p = subparsers.add_parser(
        "make-sample",
        help="rebuild the bundled sample from ModelNet40",
        description="rebuild the bundled sample from the ModelNet40 test split",
    )
    p.add_argument("--data", help="ModelNet40 folder or .npz (default: $MASKNET_DATA)")
    p.add_argument("-o", "--output", required=True, help="the .npz file to write")
    p.add_argument(
        "--per-class", type=positive_int, default=3, help="test shapes per category (default 3)"
    )


def run(args: argparse.Namespace) -> None:
    """Write the sample; print its size."""
    from masknet.data.modelnet import resolve_data_path
    from masknet.data.sample import build_sample

    refuse_inputs([args.output], [resolve_data_path(args.data)])
    path = build_sample(args.data, args.output, args.per_class)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB)")

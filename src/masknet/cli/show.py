"""``masknet show``: clouds as one offline HTML view and a PNG."""

from __future__ import annotations

import argparse
from pathlib import Path

from masknet.cli._common import (
    add_file_options,
    check_html,
)
from masknet.cli._outputs import check_outputs


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``show`` to the ``masknet`` subparsers."""
    p = subparsers.add_parser(
        "show",
        help="write an offline 3D view (HTML) and a PNG of clouds",
        description="write an interactive 3D view (one offline HTML file) and a PNG of clouds",
    )
    p.add_argument("clouds", nargs="+", help="point cloud files, one layer each")
    p.add_argument("-o", "--output", required=True, help="the .html file; the PNG goes beside it")
    p.add_argument("--title", default=None, help="the viewer's title (default: the file names)")
    add_file_options(p, html=False)


def run(args: argparse.Namespace) -> None:
    """One layer per file, named by its stem (primed where two stems agree)."""
    from masknet.io import read_points
    from masknet.viewer import write_views

    check_outputs(check_html(args.output), inputs=args.clouds)
    layers: dict = {}
    for file in args.clouds:
        name = Path(file).stem
        while name in layers:
            name += "'"
        layers[name] = read_points(file, drop_nonfinite=args.drop_nonfinite)
    title = args.title or ", ".join(Path(f).name for f in args.clouds)
    views = write_views(args.output, layers, title)
    print(f"wrote {views[0]} and {views[1]}")

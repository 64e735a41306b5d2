"""The outputs of the commands that keep some points of an input file (``mask``,
``denoise``): the kept points, with the file's colours and normals, ``<stem>_mask.txt``
(one 0/1 per row of that file) and the ``--html`` views."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from masknet._atomic import write_all
from masknet.cli._common import (
    check_html,
)
from masknet.cli._outputs import check_outputs, output_file

if TYPE_CHECKING:
    import numpy as np


def mask_outputs(args: argparse.Namespace, inputs: list[str]) -> tuple[Path, Path]:
    """``--output`` and its ``<stem>_mask.txt``, refused (with ``--html``'s files) before
    any computing if they cannot be written or would overwrite one of ``inputs``."""
    out = output_file(args.output)
    mask_path = out.with_name(out.stem + "_mask.txt")
    check_outputs([out, mask_path] + check_html(args.html), inputs=inputs)
    return out, mask_path


def write_kept(
    args: argparse.Namespace,
    paths: tuple[Path, Path],
    read_from: str,
    points: np.ndarray,
    rows: np.ndarray,
    mask: np.ndarray,
    layers: dict[str, np.ndarray],
    title: str,
) -> list[Path]:
    """Write, all or nothing, the ``points`` that ``mask`` keeps to the first of ``paths``
    (with the attributes of ``read_from``, the file ``points`` came from; ``rows``: its
    finite rows), the mask over that file's rows to the second, and with ``--html`` the
    views of ``layers``. The mask is the answer: the points it keeps are skipped with a
    warning where their format cannot hold them (none kept, as ``.ply``), so the outcome
    does not depend on the format. Returns the paths written."""
    from masknet.io import read_point_attributes, write_mask, write_points
    from masknet.io_checks import over_rows
    from masknet.viewer import view_writers

    out, mask_path = paths
    carried = read_point_attributes(read_from, out).take(rows).take(mask)
    writers = [
        (mask_path, lambda p: write_mask(p, over_rows(mask, rows))),
        (out, lambda p: write_points(p, points[mask], *carried)),
    ]
    if args.html:
        writers += view_writers(args.html, layers, title)
    write_all(writers, optional=[p for p, _ in writers[1:]])
    return [p for p, _ in writers if p.exists()]  # a skipped output is not there

"""``masknet track``: follow a known object through frames, one pose per frame."""

from __future__ import annotations

import argparse
import csv
import glob
import io
import re
import sys
from pathlib import Path

from masknet.cli._common import (
    EXIT_INTERRUPTED,
    EXIT_LIKELY_WRONG,
    EXIT_OK,
    EXIT_REFUSED,
    finite_float,
    init_option,
    positive_int,
    seed,
    start_files,
)
from masknet.cli._outputs import refuse_inputs
from masknet.errors import MaskNetError

POSES, TRAJECTORY = "poses.csv", "trajectory.png"
COLUMNS = ["frame", "file", *(f"t{i}{j}" for i in range(4) for j in range(4))]
COLUMNS += ["verdict", "state", "ms", "fitness"]
EXIT_TEXT = (
    f"exit status: {EXIT_OK} done (frames lost are in poses.csv); {EXIT_REFUSED} refused (a bad "
    f"file or option, one line; the frames before it are in poses.csv); {EXIT_LIKELY_WRONG} "
    f"the object was found in no frame; {EXIT_INTERRUPTED} interrupted (poses.csv holds the "
    "frames done, run again with --resume to go on)"
)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``track`` to the ``masknet`` subparsers."""
    p = subparsers.add_parser(
        "track",
        help="follow a known object through a stream of frames",
        description="follow TEMPLATE through FRAMES, in order: the first frame is searched "
        "(masknet register's default), the others start from the pose the last two predict "
        "and are refined by ICP near it, and searched again where the verdict drops. Writes "
        f"OUTDIR/{POSES} as it goes (frame, file, the 16 numbers of the 4x4 frame -> "
        "template transform, row by row, as masknet register writes it; verdict, state: "
        f"found, tracked, refound or lost; ms, fitness) and OUTDIR/{TRAJECTORY}",
        epilog=EXIT_TEXT,
    )
    p.add_argument("template", help="the object's points: .ply .pcd .xyz .txt .csv .npy .bin")
    p.add_argument(
        "frames",
        nargs="+",
        help="the frames, in order: files, glob patterns (quoted; expanded in natural "
        "order, frame_2 before frame_10) or @LIST (a file of paths, one a line, relative "
        "to its folder)",
    )
    p.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="output folder")
    p.add_argument(
        "--init",
        type=init_option,
        help="a file holding the 4x4 frame -> template matrix of the first frame (text or "
        ".npy): track from it instead of searching the first frame",
    )
    p.add_argument("--seed", type=seed, default=0, help="seed of the even subsets (default 0)")
    p.add_argument(
        "--viewpoint",
        type=finite_float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="the sensor's position in frame coordinates, for the searches (0 0 0 for "
        "depth frames in camera coordinates)",
    )
    p.add_argument(
        "--every",
        type=positive_int,
        metavar="K",
        help=f"{TRAJECTORY}: the template at every K-th pose (default: about 12 poses)",
    )
    p.add_argument(
        "--drop-nonfinite",
        action="store_true",
        help="drop NaN/inf rows of the files (organised depth frames) instead of refusing them",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help=f"go on after the frames an interrupted run wrote to OUTDIR/{POSES} (same "
        "frames, in the same order), from its last pose",
    )


def frame_paths(patterns: list[str]) -> list[str]:
    """The frame files named by ``patterns``, in order (see ``--help``)."""
    out: list[str] = []
    for pattern in patterns:
        if pattern.startswith("@"):
            listing = Path(pattern[1:])
            if not listing.is_file():
                raise MaskNetError(f"{listing}: no such list of frames")
            lines = [s.strip() for s in listing.read_text().splitlines()]
            out += [str(listing.parent / s) for s in lines if s and not s.startswith("#")]
        elif glob.has_magic(pattern):
            found = sorted(glob.glob(pattern), key=_natural)
            if not found:
                raise MaskNetError(f"{pattern}: no file matches")
            out += found
        else:
            out.append(pattern)
    return out


def _natural(text: str) -> list:
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", text)]


def _earlier_rows(poses: Path, frames: list[str]) -> list[dict]:
    """The rows an interrupted run wrote for the first of ``frames``; refused where
    they name other files."""
    if not poses.is_file():
        return []
    rows = list(csv.DictReader(io.StringIO(poses.read_text())))
    if len(rows) > len(frames) or any(
        r.get("file") != f for r, f in zip(rows, frames, strict=False)
    ):
        raise MaskNetError(
            f"{poses}: its frames are not the first of these frames; --resume goes on with "
            "the same frames in the same order (or give another OUTDIR)"
        )
    return rows


def _row(index: int, path: str, result) -> dict:
    row = {"frame": index, "file": path}
    row.update({f"t{i}{j}": f"{result.transform[i, j]:.9g}" for i in range(4) for j in range(4)})
    row.update(verdict=result.verdict, state=result.state, ms=f"{1000 * result.seconds:.1f}")
    row["fitness"] = f"{result.fitness:.4f}"
    return row


def _write_poses(path: Path, rows: list[dict]) -> None:
    from masknet.io import write_text_atomic

    text = io.StringIO()
    writer = csv.DictWriter(text, COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    write_text_atomic(path, text.getvalue())


def _transforms(rows: list[dict]):
    import numpy as np

    return np.array([[float(r[f"t{i}{j}"]) for i in range(4) for j in range(4)] for r in rows])


def run(args: argparse.Namespace) -> int:
    """Track; write poses.csv after every frame and trajectory.png at the end."""
    from masknet.io import read_points
    from masknet.tracking import Tracker

    frames = frame_paths(args.frames)
    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise MaskNetError(f"{out}: is a file; -o names a folder")
    poses, picture = out / POSES, out / TRAJECTORY
    refuse_inputs([poses, picture], [args.template, *frames, *start_files(args)])
    template = read_points(args.template, drop_nonfinite=args.drop_nonfinite)
    rows = _earlier_rows(poses, frames) if args.resume else []
    init = args.init  # the first frame's; a resumed run starts from its last pose
    if rows:
        init = _transforms(rows[-1:]).reshape(4, 4) if rows[-1]["state"] != "lost" else None
    tracker = Tracker(
        template,
        init=init,
        seed=args.seed,
        drop_nonfinite=args.drop_nonfinite,
        viewpoint=args.viewpoint,
    )
    try:
        for index in range(len(rows), len(frames)):
            path = frames[index]
            result = tracker.update(read_points(path, args.drop_nonfinite), name=path)
            rows.append(_row(index, path, result))
            _write_poses(poses, rows)
            print(
                f"masknet: track: {index + 1}/{len(frames)} {path}: {result.state} "
                f"({result.verdict or 'no points'}), {1000 * result.seconds:.0f} ms",
                file=sys.stderr,
                flush=True,
            )
    except KeyboardInterrupt:
        raise KeyboardInterrupt(
            f"{poses} holds the first {len(rows)} frames; --resume goes on from there"
        ) from None
    _picture(template, read_points(frames[0], args.drop_nonfinite), rows, picture, args)
    kept = sum(r["state"] != "lost" for r in rows)
    print(f"{kept} of {len(rows)} frames tracked or found; wrote {poses} and {picture}")
    return EXIT_OK if kept else EXIT_LIKELY_WRONG


def _picture(template, first, rows: list[dict], path: Path, args: argparse.Namespace) -> None:
    """trajectory.png, where matplotlib is installed (a one-line warning otherwise)."""
    from masknet.errors import warn
    from masknet.tracking.plots import plot_trajectory

    transforms = _transforms(rows).reshape(-1, 4, 4)
    try:
        plot_trajectory(
            template,
            first,
            transforms,
            [float(r["fitness"]) for r in rows],
            [r["state"] for r in rows],
            path,
            every=args.every,
            viewpoint=args.viewpoint,
            title=f"masknet track: {Path(args.template).name} through {len(rows)} frames",
        )
    except MaskNetError as exc:  # no matplotlib: the poses are the answer
        warn(f"{path}: not drawn ({exc})")

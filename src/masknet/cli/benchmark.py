"""``masknet benchmark``: the paper's experiments on seeded ModelNet40 test pairs."""

from __future__ import annotations

import argparse
import functools
import os
import sys
import time
from pathlib import Path

from masknet.cli._common import add_output_option, positive_int, seed
from masknet.errors import MaskNetError


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``benchmark`` to the ``masknet`` subparsers."""
    p = subparsers.add_parser(
        "benchmark",
        help="reproduce the paper's experiments: tables and plots",
        description="reproduce the paper's experiments on seeded ModelNet40 test pairs: "
        "table (JSON, CSV), plot (PNG), and with --results the tables of a results page",
    )
    p.add_argument(
        "experiment",
        help="registration, networks, iterations, masks-per-round, refine-masks, "
        "precision-vs-missing, protocols, rotation-sweep, noise, generalization, timing, denoising, "
        "outliers, scans, robust, real-pairs, methods, success, startup, tracking, or all",
    )
    p.add_argument("--data", help="ModelNet40 folder or .npz (default: $MASKNET_DATA)")
    p.add_argument("--pairs", type=positive_int, help="pairs per setting (default 1000)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the test pairs (default 0)")
    p.add_argument(
        "--quick",
        action="store_true",
        help="a small run (20 pairs, fewer settings; the bundled sample when no data is "
        "given); never rewrites --results",
    )
    add_output_option(
        p,
        help="folder for JSON, CSV and PNG (default masknet_benchmark)",
        old="--out",
        default="masknet_benchmark",
        metavar="OUTDIR",
    )
    p.add_argument(
        "--results",
        metavar="FILE",
        help="a markdown file whose benchmark blocks to rewrite, e.g. docs/RESULTS.md "
        "(default: none, so that a trial run leaves the published tables alone)",
    )
    p.add_argument("--threads", type=positive_int, help="torch CPU threads")
    p.add_argument(
        "--resume",
        action="store_true",
        help="after a kill: keep the table rows the interrupted run already wrote to "
        "OUTDIR/.rows (same pairs, seed, weights, data and version) and compute the rest",
    )


def run(args: argparse.Namespace) -> None:
    """Run the experiment(s); print each table, the files written and the wall time."""
    import shlex

    import torch

    from masknet.data import bundled_sample_path
    from masknet.experiments import EXPERIMENTS, BenchmarkContext, run_experiments

    names = list(EXPERIMENTS) if args.experiment == "all" else [args.experiment]
    if names[0] not in EXPERIMENTS:
        raise MaskNetError(
            f"unknown experiment {args.experiment!r}; choose from {', '.join(EXPERIMENTS)} or all"
        )
    if args.threads:
        torch.set_num_threads(args.threads)
    data_path = args.data
    if args.quick and data_path is None and not os.environ.get("MASKNET_DATA"):
        data_path = bundled_sample_path()
    results = None
    if args.results and not args.quick:
        results = Path(args.results)
        if not results.is_file():
            raise MaskNetError(f"{results}: no such results file (--results rewrites one)")
    argv = ["masknet", "benchmark", *sys.argv[2:]] if sys.argv[1:2] == ["benchmark"] else []
    ctx = BenchmarkContext(
        data=data_path,
        pairs=args.pairs or (20 if args.quick else 1000),
        seed=args.seed,
        quick=args.quick,
        out=Path(args.output),
        progress=sys.stderr.isatty(),
        command=shlex.join(argv) if argv else f"masknet benchmark {args.experiment}",
        resume=args.resume,
        log=None if sys.stderr.isatty() else functools.partial(print, file=sys.stderr, flush=True),
    )
    start = time.perf_counter()
    run_experiments(names, ctx, results, echo=functools.partial(print, flush=True))
    where = f" and {results}" if results else ""
    stems = ", ".join(str(ctx.out / name) for name in names)
    print(f"wrote {stems} (.json, .csv, .png){where}")
    print(f"wall time {time.perf_counter() - start:.0f} s")

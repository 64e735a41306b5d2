"""``masknet register-many``: many pairs in parallel, one result file per pair and a summary,
resumable after an interrupt."""

from __future__ import annotations

import argparse
import csv
import glob
import io
import json
import sys
from pathlib import Path

from masknet.cli._common import (
    EXIT_LIKELY_WRONG,
    EXIT_SOME_FAILED,
    add_output_option,
    exit_codes_text,
    finite_float,
    init_option,
    positive_int,
    start_files,
)
from masknet.cli._outputs import check_outputs
from masknet.errors import MaskNetError
from masknet.registration.terms.methods import METHODS

SUMMARY = "summary.csv"
COLUMNS = (
    "name", "template", "source", "status", "verdict", "rotation_deg", "translation",
    "fitness", "inlier_rmse", "seconds", "error", "warnings",
)  # fmt: skip


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``register-many`` to the ``masknet`` subparsers."""
    p = subparsers.add_parser(
        "register-many",
        help="register many pairs on every core (resumable)",
        description="register many pairs in parallel (all cores, or a Dask cluster): one result "
        "per pair and summary.csv in OUTDIR; run it again to finish an interrupted batch",
        epilog=exit_codes_text(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    given = p.add_mutually_exclusive_group(required=True)
    given.add_argument(
        "--list",
        metavar="FILE",
        help="a text file, one pair per line: TEMPLATE SOURCE [NAME] ('#' starts a comment; "
        "relative paths are relative to the file); NAME defaults to the source's stem",
    )
    given.add_argument("--template", metavar="FILE", help="one template for every --sources")
    p.add_argument(
        "--sources", metavar="GLOB", help="with --template: the sources, a glob ('scans/*.pcd')"
    )
    add_output_option(
        p,
        help="the folder of the results: NAME.json and NAME_transform.txt per pair, and "
        f"{SUMMARY} (pose, fitness, verdict, time; failed pairs with their error)",
        old="--out",
        required=True,
        metavar="OUTDIR",
    )
    p.add_argument(
        "--workers",
        type=positive_int,
        help="processes, one thread each (default: one per core)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on the workers of this Dask scheduler (tcp://host:8786) instead; needs "
        "pip install 'masknet[cluster]', and every worker must read the files' paths",
    )
    p.add_argument("--method", choices=list(METHODS), default=None, help="as masknet register")
    p.add_argument("--iterations", type=positive_int, default=1, help="as masknet register")
    p.add_argument(
        "--init",
        type=init_option,
        default="centroid",
        metavar="{centroid,identity,FILE}",
        help="as masknet register (one start for every pair)",
    )
    p.add_argument(
        "--max-correspondence-distance", type=finite_float, metavar="D", help="as masknet register"
    )
    p.add_argument("--no-mask", action="store_true", help="plain X instead of Mask-X")
    p.add_argument("--drop-nonfinite", action="store_true", help="drop NaN/inf rows of the files")
    p.add_argument(
        "--exit-zero",
        action="store_true",
        help="exit 0 even when some results are likely wrong or some pairs failed",
    )


def read_jobs(args: argparse.Namespace):
    """The pairs the options name, as PairJobs with unique names."""
    from masknet.registration.many import PairJob

    rows: list[tuple[str, str, str | None]] = []
    if args.list:
        path = Path(args.list)
        if not path.is_file():
            raise MaskNetError(f"{path}: no such list file")
        for number, line in enumerate(path.read_text().splitlines(), 1):
            fields = line.split("#", 1)[0].split()
            if not fields:
                continue
            if len(fields) not in (2, 3):
                raise MaskNetError(f"{path}:{number}: expected TEMPLATE SOURCE [NAME]")
            # Relative paths are relative to the list file, wherever the command runs.
            template, source = (str(path.parent / f) for f in fields[:2])
            rows.append((template, source, fields[2] if len(fields) == 3 else None))
    else:
        if not args.sources:
            raise MaskNetError("--template needs --sources GLOB")
        sources = sorted(glob.glob(args.sources))
        if not sources:
            raise MaskNetError(f"--sources {args.sources!r} matches no file")
        rows = [(args.template, s, None) for s in sources]
    if not rows:
        raise MaskNetError("no pairs to register")
    jobs, seen = [], set()
    for template, source, name in rows:
        base = name or Path(source).stem
        if "/" in base or "\\" in base or base in (".", "..") or not base:
            raise MaskNetError(f"pair name {base!r}: a name is a file stem, without folders")
        unique, k = base, 2
        while unique.lower() in seen:  # names that differ only by case collide on some disks
            unique, k = f"{base}_{k}", k + 1
        seen.add(unique.lower())
        jobs.append(PairJob(unique, template, source))
    return jobs


def check_options(options: dict) -> None:
    """Refuse, once and before any pair, what ``register`` would refuse for every pair."""
    from masknet.registration.terms.methods import default_method, method_options
    from masknet.registration.terms.validation import (
        as_rigid_transforms,
        check_arguments,
        split_init,
    )

    init = options["init"]
    method = default_method(options.get("method"), None)
    check_arguments(method, options["iterations"], None, None, options["use_mask"], init, 0, 1024)
    _, start = split_init(init)
    if start is not None:
        as_rigid_transforms(start, 1)
    cut = options.get("max_correspondence_distance")
    method_options(method, None, {} if cut is None else {"max_correspondence_distance": cut})


def _options_key(options: dict) -> dict:
    """The options as a record stores them (a start matrix as nested lists)."""
    import numpy as np

    return {k: (np.asarray(v).tolist() if not isinstance(v, str | bool | int | float) else v)
            for k, v in sorted(options.items())}  # fmt: skip


def _earlier(out: Path, job) -> dict | None:
    """The record an earlier run left for this pair's name, whatever its files and options;
    None where there is none (or it cannot be read)."""
    try:
        record = json.loads((out / f"{job.name}.json").read_text())
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) else None


def _is_same(record: dict | None, job, options: dict) -> bool:
    """Whether ``record`` is of this pair's files with these options."""
    return record is not None and (
        record.get("template"),
        record.get("source"),
        record.get("options"),
    ) == (str(job.template), str(job.source), _options_key(options))


def _record_of(out: Path, job, options: dict) -> dict | None:
    """The record an earlier run left for this pair with the same files and options, or
    None."""
    record = _earlier(out, job)
    return record if _is_same(record, job, options) else None


def _plan(out: Path, jobs, options: dict) -> tuple[list, int]:
    """The jobs to run: those not registered earlier with the same files and options (a
    pair that failed is tried again); and how many of them replace an earlier result
    made with other files or options."""
    todo, replaced = [], 0
    for job in jobs:
        record = _earlier(out, job)
        if not _is_same(record, job, options):
            todo.append(job)
            replaced += record is not None
        elif record.get("status") != "registered":
            todo.append(job)
    return todo, replaced


def _record(job, outcome, options: dict) -> dict:
    """The JSON record of one finished pair."""
    import numpy as np

    record = {
        "name": job.name,
        "template": str(job.template),
        "source": str(job.source),
        "options": _options_key(options),
        "warnings": " | ".join(outcome.warnings),
    }
    if outcome.error:
        return record | {"status": "failed", "error": outcome.error, "seconds": outcome.seconds}
    result = outcome.result
    return record | {
        "status": "registered",
        "verdict": outcome.verdict,
        "reason": outcome.reason,
        "transform": np.asarray(result.transform).tolist(),
        "rotation_deg": float(result.rotation_deg),
        "translation": float(np.linalg.norm(result.t)),
        "fitness": None if result.fitness is None else float(result.fitness),
        "inlier_rmse": None if result.inlier_rmse is None else float(result.inlier_rmse),
        "method": result.method,
        "seconds": outcome.seconds,
    }


def _write_record(out: Path, record: dict) -> None:
    from masknet.io import write_text_atomic
    from masknet.registration.many import transform_text

    transform_path = out / f"{record['name']}_transform.txt"
    if record["status"] == "registered":
        import numpy as np

        write_text_atomic(transform_path, transform_text(np.array(record["transform"])))
    else:  # an earlier run's pose of this pair is not this run's
        transform_path.unlink(missing_ok=True)
    # The record last: it marks the pair finished.
    write_text_atomic(out / f"{record['name']}.json", json.dumps(record, indent=1) + "\n")


def _write_summary(out: Path, jobs, options: dict) -> list[dict]:
    """summary.csv from the records of this batch's pairs (same files and options), in the
    jobs' order."""
    from masknet.io import write_text_atomic

    records = [r for r in (_record_of(out, job, options) for job in jobs) if r is not None]
    text = io.StringIO()
    writer = csv.DictWriter(text, COLUMNS, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    writer.writerows(records)
    write_text_atomic(out / SUMMARY, text.getvalue())
    return records


def _check_results(args: argparse.Namespace, jobs, out: Path, started_from: list[str]) -> None:
    """The output rule, before any work: ``out`` is a folder (or not made yet), and no
    result file (``NAME.json``, ``NAME_transform.txt``, ``summary.csv``) is one of the
    inputs (the list file, a pair's files, ``--init``'s file), through a link neither."""
    if out.exists() and not out.is_dir():
        raise MaskNetError(f"{out}: is a file; the results of a batch go into a folder")
    if out.is_symlink() and not out.exists():
        raise MaskNetError(f"{out}: is a link to nothing; the results of a batch go into a folder")
    inputs = [args.list] if args.list else []
    inputs += started_from
    inputs += [path for job in jobs for path in (job.template, job.source)]
    text = (".txt", ".json", ".csv")
    check_outputs([out / SUMMARY], text, inputs, hint="give the results another folder")
    outputs = [out / f"{job.name}{end}" for job in jobs for end in ("_transform.txt", ".json")]
    hint = "give the pair another NAME, or the results another folder"
    check_outputs(outputs, text, inputs, hint=hint)


def run(args: argparse.Namespace) -> int:
    """Register the pairs not finished yet; write each result as it comes, then the
    summary. Returns the exit status."""
    from masknet.registration.many import executor, run_jobs

    jobs = read_jobs(args)
    started_from = start_files(args)
    options = {"use_mask": not args.no_mask, "iterations": args.iterations, "init": args.init}
    options |= {"drop_nonfinite": True} if args.drop_nonfinite else {}
    if args.method is not None:
        options["method"] = args.method
    if args.max_correspondence_distance is not None:
        options["max_correspondence_distance"] = args.max_correspondence_distance
    check_options(options)
    out = Path(args.output)
    _check_results(args, jobs, out, started_from)
    # No folder made here: the first file written makes it, so an interrupt before leaves
    # none behind.
    todo, replaced = _plan(out, jobs, options)
    skipped = len(jobs) - len(todo)
    print(
        f"{len(jobs):,} pairs; {skipped:,} finished earlier, {len(todo):,} to register"
        + (f" on {args.scheduler}" if args.scheduler else ""),
        file=sys.stderr,
    )
    if replaced:
        print(
            f"masknet: warning: earlier results in {out} made with other files or options "
            f"are replaced: {replaced:,} of {len(jobs):,} pairs",
            file=sys.stderr,
        )
    by_name = {job.name: job for job in todo}
    count = [skipped]

    def done(outcome) -> None:
        record = _record(by_name[outcome.name], outcome, options)
        _write_record(out, record)
        count[0] += 1
        what = record.get("verdict") or f"failed: {record['error']}"
        print(f"masknet: [{count[0]}/{len(jobs)}] {outcome.name}: {what}, {outcome.seconds:.2f} s",
              file=sys.stderr, flush=True)  # fmt: skip

    records: list[dict] = []
    try:
        if todo:
            with executor(args.workers, args.scheduler) as pool:
                run_jobs(todo, options, pool, done)
    except KeyboardInterrupt:
        raise KeyboardInterrupt(
            f"{count[0]:,} of {len(jobs):,} pairs are finished in {out}; the same command "
            "again registers the rest"
        ) from None
    finally:  # the summary of what is finished, after an interrupt too; no folder, none
        if out.is_dir():
            records = _write_summary(out, jobs, options)
    try:
        return _report(args, records, out)
    except KeyboardInterrupt:  # every result is on disk: say so, and still exit 130
        raise KeyboardInterrupt(f"the results are written in {out}") from None


def _report(args: argparse.Namespace, records: list[dict], out: Path) -> int:
    """Print the batch's counts; the exit status they give."""
    failed = sum(r["status"] == "failed" for r in records)
    wrong = sum(r.get("verdict") == "likely wrong" for r in records)
    print(
        f"{len(records) - failed:,} registered ({wrong:,} likely wrong), {failed:,} failed; "
        f"wrote {out / SUMMARY}"
    )
    if args.exit_zero:
        return 0
    return EXIT_SOME_FAILED if failed else EXIT_LIKELY_WRONG if wrong else 0

"""The table of experiments, and running them: files, the results block, the wall times."""

from __future__ import annotations

import json
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path

import torch

from masknet.errors import MaskNetError
from masknet.experiments import (
    denoising,
    generalization,
    iterations,
    methods,
    networks,
    noise,
    outliers,
    precision_vs_missing,
    protocols,
    real_pairs,
    registration,
    robust,
    rotation_sweep,
    rounds,
    scans,
    startup,
    success,
    timing,
    tracking,
)
from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.experiments.report import csv_text, markdown_table, update_results
from masknet.io import write_text_atomic

__all__ = ["EXPERIMENTS", "run_benchmark", "run_experiments"]

# Name (as `masknet benchmark NAME` takes it) -> the experiment, in the order `all` runs them.
EXPERIMENTS: dict[str, Callable[[BenchmarkContext], ExperimentResult]] = {
    "registration": registration.run,
    "networks": networks.run,
    "iterations": iterations.run,
    "masks-per-round": rounds.masks_per_round,
    "refine-masks": rounds.refine_masks,
    "precision-vs-missing": precision_vs_missing.run,
    "protocols": protocols.run,
    "rotation-sweep": rotation_sweep.run,
    "noise": noise.run,
    "generalization": generalization.run,
    "timing": timing.run,
    "denoising": denoising.run,
    "outliers": outliers.run,
    "scans": scans.run,
    "robust": robust.run,
    "real-pairs": real_pairs.run,
    "methods": methods.run,
    "success": success.run,
    "startup": startup.run,
    "tracking": tracking.run,
}


def _machine() -> str:
    return f"{platform.machine()}, {os.cpu_count()} CPUs, torch {torch.__version__}"


def run_benchmark(
    name: str, ctx: BenchmarkContext, results: Path | None = None
) -> ExperimentResult:
    """Run one experiment, write its files, and update ``results`` (markdown) if given."""
    if name not in EXPERIMENTS:
        raise MaskNetError(
            f"unknown experiment {name!r}; choose from {', '.join(EXPERIMENTS)} or all"
        )
    ctx.out.mkdir(parents=True, exist_ok=True)
    ctx.start_experiment(name)
    start = time.perf_counter()
    result = EXPERIMENTS[name](ctx)
    wall = time.perf_counter() - start
    reused = dict(ctx.reused)
    stem = ctx.out / name
    payload = {
        "experiment": name,
        "pairs": ctx.pairs,
        "seed": ctx.seed,
        "quick": ctx.quick,
        "wall_time_s": wall,
        "resumed_rows": reused["rows"],  # rows kept from earlier invocations (--resume)
        "resumed_seconds": reused["seconds"],  # what computing those rows took then
        "threads": torch.get_num_threads(),
        "machine": _machine(),
        "summary": result.summary,
        "rows": result.rows,
    }
    write_text_atomic(stem.with_suffix(".json"), json.dumps(payload, indent=2) + "\n")
    write_text_atomic(stem.with_suffix(".csv"), csv_text(result.rows))
    if result.plot is not None:
        result.plot(stem.with_suffix(".png"))
    if results is not None:
        took = f"{wall / 60:.1f} min"
        if reused["rows"]:
            took += (
                f", plus {reused['seconds'] / 60:.1f} min for {reused['rows']} rows kept from "
                "an interrupted invocation"
            )
        lines = [
            f"`{ctx.command}` ({took}, {payload['machine']}, {payload['threads']} threads)",
            "",
            result.summary,
            "",
            markdown_table(result.rows),
        ]
        if result.plot is not None:
            rel = os.path.relpath(stem.with_suffix(".png"), results.parent)
            lines += ["", f"![{name}]({rel})"]
        update_results(results, name, "\n".join(lines))
    return result


def run_experiments(
    names: list[str],
    ctx: BenchmarkContext,
    results: Path | None = None,
    echo: Callable[[str], None] = lambda line: None,
) -> list[dict]:
    """Run several experiments in order; returns one row each (name, minutes, status).

    An experiment that raises :class:`MaskNetError` (e.g. no scan folder) is skipped
    and the others still run; a single experiment re-raises. With ``results`` and more
    than one experiment, the run's wall times go to its ``benchmark:all`` block.
    """
    start = time.perf_counter()
    log = []
    for name in names:
        tic = time.perf_counter()
        try:
            result = run_benchmark(name, ctx, results)
        except MaskNetError as exc:
            if len(names) == 1:
                raise
            echo(f"== {name}: skipped ({exc})")
            log.append({"experiment": name, "minutes": 0.0, "status": f"skipped: {exc}"})
            continue
        minutes = (time.perf_counter() - tic) / 60
        status = "done"
        if ctx.reused["rows"]:
            status += (
                f"; {ctx.reused['rows']} rows ({ctx.reused['seconds'] / 60:.1f} min) kept from "
                "an interrupted invocation"
            )
        log.append({"experiment": name, "minutes": minutes, "status": status})
        echo(f"== {name} ({60 * minutes:.0f} s): {result.summary}")
        echo(markdown_table(result.rows))
    if results is not None and len(names) > 1:
        wall = (time.perf_counter() - start) / 60
        update_results(
            results,
            "all",
            f"`{ctx.command}`: {wall:.1f} min in all, {torch.get_num_threads()} threads, "
            f"{platform.machine()}, {os.cpu_count()} CPUs, torch {torch.__version__}\n\n"
            + markdown_table(log),
        )
    return log

"""``startup``: what a ``masknet`` command costs before and around its own work.

Each command runs as a new process, as a user runs it, and is timed from start to exit
(the median of a few runs). A refused call (a missing file) must answer before torch is
imported; a registration pays the imports once per call, which the table separates from
the registration itself (timed in this process, warm).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

from masknet.experiments.context import BenchmarkContext, ExperimentResult, median_time


def _wall(argv: list[str], repeats: int) -> tuple[float, int]:
    """Median seconds from start to exit of ``argv``, and its exit code."""
    done, seconds = median_time(lambda: subprocess.run(argv, capture_output=True), repeats)
    return seconds, done.returncode


def run(ctx: BenchmarkContext) -> ExperimentResult:
    """Wall time of CLI calls and of the imports behind them, in fresh processes."""
    from masknet import register
    from masknet.io import write_points

    repeats = 1 if ctx.quick else 5
    cli = [sys.executable, "-m", "masknet.cli"]
    pair = ctx.test_pairs(count=1)
    template, source = pair.template[0].double().numpy(), pair.source[0].double().numpy()
    for _ in range(3):  # warm (weights read, kernels chosen): the figure is the work alone
        register(template, source)
    tic = time.perf_counter()
    for _ in range(repeats):
        register(template, source)
    work = (time.perf_counter() - tic) / repeats
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        t, s, missing = (str(Path(folder) / n) for n in ("t.xyz", "s.xyz", "missing.ply"))
        write_points(t, template)
        write_points(s, source)
        calls = {
            "masknet --version": [*cli, "--version"],
            "masknet register, a missing file (refused)": [*cli, "register", missing, t],
            "python -c 'import torch'": [sys.executable, "-c", "import torch"],
            "python -c 'import open3d'": [sys.executable, "-c", "import open3d"],
            "masknet register, a ModelNet40 test pair": [
                *cli,
                "register",
                t,
                s,
                "-o",
                str(Path(folder) / "out.xyz"),
            ],  # fmt: skip
        }
        for name, argv in calls.items():
            seconds, code = _wall(argv, repeats)
            row = {"call": name, "seconds": seconds, "exit_code": code}
            if name.startswith("masknet register, a ModelNet40"):
                row["registration_s"] = work
                row["start_up_s"] = seconds - work
            rows.append(row)
    summary = (
        f"Seconds from process start to exit, median of {repeats} runs; the registration "
        "row also gives the same register() call timed in a warm process and the "
        "difference, the start-up a command-line user pays per call (imports of numpy, "
        "torch and, for some inputs and methods, Open3D; reading the weights; the first call's "
        "one-time costs in torch)."
    )
    return ExperimentResult(rows, summary)

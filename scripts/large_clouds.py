"""Time and peak memory of ``masknet register`` on large clouds, as a user runs it.

    python scripts/large_clouds.py --scans ../shared/data/scans --out docs/results/large_clouds.json

Cases: a 2,000,000-point template with a 1,200,000-point partial source (a ModelNet40
sample shape's surface, densified with small noise), and the 3DMatch fragment
(``fragment.pcd``, and a random 19,000 of its points) against its own 60% view. Each runs ``masknet register`` in a fresh
process; wall time and peak resident memory come from ``resource.getrusage`` of the
child.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from masknet.cli import run_script
from masknet.data import bundled_sample_path, load_modelnet40
from masknet.io import read_points


def _dense(shape: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    picks = rng.integers(0, len(shape), count)
    return shape[picks] + rng.normal(0, 0.004, (count, 3))


def _run(args: list[str]) -> dict:
    """Run ``masknet ARGS`` in a child process: its wall time and peak resident memory."""
    import os

    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        tic = time.perf_counter()
        child = subprocess.Popen(
            [sys.executable, "-m", "masknet.cli", *args], stdout=out, stderr=err
        )
        _, status, usage = os.wait4(child.pid, 0)  # the rusage of this child alone
        seconds = time.perf_counter() - tic
        child.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        if child.returncode != 0:
            raise SystemExit(f"masknet {' '.join(args)} failed:\n{err.read()}")
        lines = out.read().splitlines()
    return {"seconds": seconds, "peak_rss_gib": usage.ru_maxrss / 2**20, "stdout": lines}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scans", default="../shared/data/scans")
    p.add_argument("--out")
    args = p.parse_args()
    rng = np.random.default_rng(0)
    shape = load_modelnet40(bundled_sample_path(), "test").points[0].astype(np.float64)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        big = _dense(shape, 2_000_000, rng)
        part = big[big[:, 0] > np.quantile(big[:, 0], 0.4)][:1_200_000] + [0.1, 0.0, 0.05]
        np.save(d / "big.npy", big)
        np.save(d / "big_part.npy", part)
        fragment = read_points(Path(args.scans) / "fragment.pcd", drop_nonfinite=True)
        view = fragment[fragment[:, 0] < np.quantile(fragment[:, 0], 0.6)] + [0.05, 0.0, 0.0]
        np.save(d / "fragment.npy", fragment)
        np.save(d / "view.npy", view)
        small = fragment[rng.choice(len(fragment), 19_000, replace=False)]
        np.save(d / "fragment19k.npy", small)
        np.save(
            d / "view19k.npy", small[small[:, 0] < np.quantile(small[:, 0], 0.6)] + [0.05, 0, 0]
        )
        cases = {
            f"2,000,000 + {len(part):,} points": ["big.npy", "big_part.npy"],
            f"3DMatch fragment, {len(fragment):,} + {len(view):,} points": [
                "fragment.npy",
                "view.npy",
            ],
            "3DMatch fragment, 19,000 + 11,400 points": ["fragment19k.npy", "view19k.npy"],
        }
        for name, (template, source) in cases.items():
            cmd = ["register", str(d / template), str(d / source), "-o", str(d / "out.npy")]
            row = {"case": name, **_run(cmd)}
            # register()'s own time, as the command prints it ("...; 123.4 ms").
            line = next(x for x in row["stdout"] if x.startswith("rotation"))
            row["register_ms"] = float(line.rsplit(";", 1)[1].split()[0])
            mask = _run(["mask", str(d / template), str(d / source), "-o", str(d / "in.npy")])
            row["mask_seconds"], row["mask_peak_rss_gib"] = mask["seconds"], mask["peak_rss_gib"]
            rows.append(row)
            print(
                f"{name}: {row['seconds']:.1f} s for the command, {row['register_ms']:.0f} ms in "
                f"register, peak {row['peak_rss_gib']:.2f} GiB; masknet mask "
                f"{row['mask_seconds']:.1f} s, peak {row['mask_peak_rss_gib']:.2f} GiB",
                flush=True,
            )
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    run_script(main)

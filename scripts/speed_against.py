"""The default ``register`` of this checkout against that of another revision, side by side.

    python scripts/speed_against.py --rev 7a19b16 --pairs 60 --passes 4 --out docs/results/speed_against.json

Each version runs in its own process (the other revision from a temporary git worktree),
the two alternating pass by pass on the same seeded ModelNet40 test pairs (the bundled
sample), so that a busy moment of the machine falls on both alike. Every process warms up
first; the figures are medians of single-pair ``register(template, source)`` calls, over
all calls and over those the fast path settled.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from masknet.cli import run_script

ROOT = Path(__file__).resolve().parents[1]

# Run in each version's process: the public API only, so that any revision can run it.
_TIMING = """
import json, sys, time
import numpy as np, torch
import masknet
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
torch.set_num_threads(int(sys.argv[2]))
shapes = load_modelnet40(bundled_sample_path(), "test").points
pairs = make_test_pairs(shapes, int(sys.argv[1]), PairConfig(), seed=7)
T, S = pairs.template.double().numpy(), pairs.source.double().numpy()
for i in range(3):
    masknet.register(T[i], S[i])
seconds, paths = [], []
for i in range(len(T)):
    tic = time.perf_counter()
    result = masknet.register(T[i], S[i])
    seconds.append(time.perf_counter() - tic)
    paths.append(str(result.info.get("path", "")))
print(json.dumps({"seconds": seconds, "paths": paths}))
"""


def _pass(src: Path, pairs: int, threads: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src)}  # this version's package first
    out = subprocess.run(
        [sys.executable, "-c", _TIMING, str(pairs), str(threads)],
        capture_output=True,
        text=True,
        env=env,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rev", required=True, help="the git revision to compare against")
    parser.add_argument("--pairs", type=int, default=60)
    parser.add_argument("--passes", type=int, default=4, help="passes per version")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, help="JSON file for the figures")
    args = parser.parse_args()

    calls: dict[str, dict[str, list]] = {
        v: {"seconds": [], "paths": []} for v in ("this", args.rev)
    }
    with tempfile.TemporaryDirectory() as folder:
        other = Path(folder) / "other"
        git = ["git", "-C", str(ROOT)]
        subprocess.run([*git, "worktree", "add", "--detach", str(other), args.rev], check=True)
        try:
            for _ in range(args.passes):
                for version, src in (("this", ROOT / "src"), (args.rev, other / "src")):
                    run = _pass(src, args.pairs, args.threads)
                    for key in ("seconds", "paths"):
                        calls[version][key] += run[key]
        finally:
            subprocess.run([*git, "worktree", "remove", "--force", str(other)], check=True)

    rows = {}
    for version, run in calls.items():
        seconds = np.array(run["seconds"])
        fast = seconds[np.array(run["paths"]) == "fast"]
        rows[version] = {
            "median_ms": 1e3 * float(np.median(seconds)),
            "fast_path_median_ms": 1e3 * float(np.median(fast)) if len(fast) else None,
            "fast_share": len(fast) / len(seconds),
            "calls": len(seconds),
        }
        print(
            f"{version}: median {rows[version]['median_ms']:.2f} ms, fast path "
            f"{rows[version]['fast_path_median_ms']:.2f} ms ({len(fast)} of {len(seconds)} calls)"
        )
    if args.out:
        machine = f"{platform.machine()}, {args.threads} threads"
        args.out.write_text(json.dumps({"machine": machine, "rows": rows}, indent=2) + "\n")


if __name__ == "__main__":
    run_script(main)

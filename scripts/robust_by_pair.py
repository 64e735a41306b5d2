"""The default ``register`` pair by pair on sets of the robust benchmark
(``masknet benchmark robust``'s pairs, the same seed): each pair's rotation error, path and
seconds, and per set the mean error and the median time. Run it with two checkouts on
``PYTHONPATH`` in turn to see which pairs a change moves::

    python scripts/robust_by_pair.py --data $DATA --sets "scans, shared points" --out new.json

The scan sets read the evaluation scans from ``$MASKNET_SCANS`` (default
../shared/data/scans).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from masknet import register
from masknet.cli import run_script
from masknet.evaluation.registration import pair_arrays, pose_errors
from masknet.experiments.context import BenchmarkContext
from masknet.experiments.robust import benchmark_sets

SPARSE = ("resampled", "scans, re-sampled", "scans, shared points")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True, help="ModelNet40 folder or .npz")
    parser.add_argument("--pairs", type=int, default=100, help="pairs per set (default 100)")
    parser.add_argument("--sets", default=";".join(SPARSE), help="set names, ';'-separated")
    parser.add_argument("--out", help="write the per-pair figures here (.json)")
    args = parser.parse_args()
    ctx = BenchmarkContext(data=args.data, pairs=args.pairs, seed=0)
    sets = benchmark_sets(ctx, args.pairs)
    found = {}
    for name in args.sets.split(";"):
        if sets.get(name) is None:
            print(f"{name}: not available (unknown, or its scans are missing)")
            continue
        template, source, truth = pair_arrays(sets[name])
        register(template[0], source[0])  # the networks loaded before the clock
        estimates, seconds, paths = np.empty_like(truth), [], []
        for i in range(len(truth)):
            tic = time.perf_counter()
            result = register(template[i], source[i])
            seconds.append(time.perf_counter() - tic)
            estimates[i] = result.transform
            paths.append(str(result.info.get("path", "")))
        rotation, _ = pose_errors(estimates, truth)
        found[name] = {"rotation_deg": rotation.tolist(), "seconds": seconds, "path": paths}
        print(f"{name}: mean {rotation.mean():.4g} deg, median {1e3 * np.median(seconds):.3g} ms")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(found, f)


if __name__ == "__main__":
    run_script(main)

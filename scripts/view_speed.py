"""The default against the best-tuned Open3D peer on real scan views: errors and median time.

    python scripts/view_speed.py [--per-scan 14] [--out FILE.json]

The views of ``scripts/slide_views.py`` (``scan_eval_set``: 70% views of 4,096-point
templates cut from the evaluation scans, noise 0.2% of the radius, metres, seed 0), with the
source's points copied and re-sampled. Each peer (Open3D's FPFH + RANSAC or FGR, then ICP)
runs at every voxel of the robust benchmark (fractions of the template's radius), normals
as they come and turned towards the centroid; the best is the most accurate, and among
settings as accurate the fastest (the robust benchmark's rule). Times are single-pair
``register`` calls, median over the views, on the threads torch and Open3D are given.
"""

from __future__ import annotations

import argparse
import json
import warnings

from masknet.cli import run_script


def main() -> None:
    from masknet.experiments.robust import DEFAULT, PEERS, VOXELS, pipelines, timed_errors
    from masknet.experiments.rounds import scan_eval_set

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-scan", type=int, default=14)
    parser.add_argument("--out", help="write every row here (.json)")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    settings = {
        name: kwargs
        for name, kwargs in pipelines(VOXELS).items()
        if name == DEFAULT or name.startswith(PEERS)
    }
    rows = []
    print("| views | default mean / median deg | ms | best peer | mean / median deg | ms | ratio |")
    print("|---|---|---|---|---|---|---|")
    for kind, copied in (("copied", True), ("re-sampled", False)):
        pairs, _ = scan_eval_set(args.per_scan, copied, 0)
        found = {name: timed_errors(pairs, **kwargs) for name, kwargs in settings.items()}
        rows += [{"views": kind, "pipeline": name, **row} for name, row in found.items()]
        peers = {name: row for name, row in found.items() if name != DEFAULT}
        lowest = min(row["rot_mean"] for row in peers.values())
        level = [n for n, r in peers.items() if r["rot_mean"] <= max(1.01 * lowest, lowest + 0.01)]
        best = min(level, key=lambda n: peers[n]["ms_median"])
        ours, theirs = found[DEFAULT], peers[best]
        print(
            f"| {kind} ({len(pairs.template)}) | {ours['rot_mean']:.3g} / "
            f"{ours['rot_median']:.3g} | {ours['ms_median']:.3g} | {best} | "
            f"{theirs['rot_mean']:.3g} / {theirs['rot_median']:.3g} | "
            f"{theirs['ms_median']:.3g} | {ours['ms_median'] / theirs['ms_median']:.2f} |",
            flush=True,
        )
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    run_script(main)

"""The default on real scan views: which results lie beyond 5 degrees or 5% of the radius, and
how the consensus front end ended their calls.

    python scripts/slide_views.py [--per-scan 14] [--resampled] [--folder DIR]

Views of the success benchmark's kind (``scan_eval_set``: 70% views of 4,096-point
templates, noise 0.2% of the radius), ``--per-scan`` per scan of ``--folder`` (default the
evaluation scans), the source's points copied (or re-sampled with ``--resampled``), seed 0.
Prints the count of right answers (within 5 degrees and 5% of the template's largest radius)
and how many the verdict calls ``likely correct``, then one Markdown row per other result:
its error, ``info["path"]``, the verdict and overlap fit of ``assess_registration``, and the
front end's verdict on the pose as given (refined, judged first) and how far off that pose
is. docs/RESULTS.md, "A verdict that sees a slide".
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from masknet.cli import run_script


def main() -> None:
    import open3d as o3d

    from masknet import assess_registration, register
    from masknet.evaluation.registration import pose_errors
    from masknet.experiments.rounds import scan_eval_set
    from masknet.geometry.clouds import centroid_radius
    from masknet.registration.solvers.open3d_icp import centroids_matched
    from masknet.registration.stages import consensus
    from masknet.registration.terms.options import RobustOptions

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-scan", type=int, default=14)
    parser.add_argument("--resampled", action="store_true")
    parser.add_argument("--folder", default=None)
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    pairs, names = scan_eval_set(args.per_scan, not args.resampled, 0, folder=args.folder)

    def off(pose: np.ndarray, truth: np.ndarray, radius: float) -> tuple[float, float]:
        rot, trans = pose_errors(pose[None], truth[None])
        return float(rot[0]), float(trans[0]) / radius

    right = called = 0
    rows = []
    for i, name in enumerate(names):
        template, source, truth = (
            x[i].double().numpy() for x in (pairs.template, pairs.source, pairs.transform)
        )
        radius = float(centroid_radius(template))
        result = register(template, source)
        degrees, shift = off(result.transform, truth, radius)
        check = assess_registration(template, source, result.transform)
        if degrees <= 5 and shift <= 0.05:
            right += 1
            called += check.verdict == "likely correct"
            continue
        # The front end's first step: the pose as given, refined and judged on its grid.
        grids = consensus._grids(o3d, template, source, RobustOptions())
        start = consensus._point_to_plane(
            grids, centroids_matched(*grids.coarse, consensus.START_ITERATIONS)
        )
        start_degrees, start_shift = off(start, truth, radius)
        rows.append(
            f"| {i} {name} | {degrees:.2f}°, {shift:.1%} | {np.atleast_1d(result.info['path'])[0]} "
            f"| {check.verdict} | {check.overlap_fit:.2f} | "
            f"{consensus.judge(grids.check, start).verdict}, {start_degrees:.2f}°, "
            f"{start_shift:.1%} |"
        )
    print(f"{len(names)} views: {right} right, {called} of them called likely correct")
    print("| view | error | path | verdict | overlap fit | the pose as given |")
    print("|---|---|---|---|---|---|")
    print("\n".join(rows))


if __name__ == "__main__":
    run_script(main)

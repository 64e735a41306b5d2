"""One real-scan view of ``scripts/slide_views.py``, traced: every pose the verdict judged on
the way to the default's answer, and what the verdict sees at the truth and at that answer.

    python scripts/view_trace.py VIEW [--resampled] [--per-scan 14] [--folder DIR]

VIEW is the row number that ``slide_views.py`` prints (the same set: ``scan_eval_set``, seed
0). Prints the share of the front end's first-grid points whose normal is undefined by the
points within 2 voxels (under three of them, or on a line: a lidar ring), then one line per
pose judged during ``register`` (its turn from the truth, not its shift: ``register``
judges in a frame of its own; its verdict, overlap fit and nearest fit), then for the truth and the answer on the whole clouds: the
verdict, both directions of the overlap fit and the share of each cloud in the overlap
(within 3 inlier distances of the other). docs/RESULTS.md, "A verdict that sees a slide".
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from masknet.cli import run_script


def main() -> None:
    import open3d as o3d

    from masknet import register
    from masknet.evaluation.registration import pose_errors
    from masknet.experiments.rounds import scan_eval_set
    from masknet.geometry.clouds import centroid_radius
    from masknet.geometry.knn import cloud_tree
    from masknet.geometry.open3d_clouds import undefined_normals
    from masknet.geometry.se3 import transform_points
    from masknet.registration.judge import assessment
    from masknet.registration.judge.fit import overlap_fit
    from masknet.registration.judge.prepared import PreparedPair
    from masknet.registration.stages import auto, consensus
    from masknet.registration.terms.options import RobustOptions

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("view", type=int)
    parser.add_argument("--per-scan", type=int, default=14)
    parser.add_argument("--resampled", action="store_true")
    parser.add_argument("--folder", default=None)
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    pairs, names = scan_eval_set(args.per_scan, not args.resampled, 0, folder=args.folder)
    i = args.view
    template, source, truth = (
        x[i].double().numpy() for x in (pairs.template, pairs.source, pairs.transform)
    )
    radius = float(centroid_radius(template))

    def off(pose: np.ndarray) -> str:
        rot, trans = pose_errors(pose[None], truth[None])
        return f"{float(rot[0]):.1f}°, {float(trans[0]) / radius:.1%}"

    grids = consensus._grids(o3d, template, source, RobustOptions(), True)
    for side, cloud in zip(("template", "source"), grids.coarse, strict=True):
        share = undefined_normals(np.asarray(cloud.points), 2 * grids.voxel).mean()
        print(f"{names[i]} view {i}, {side}'s first grid: {share:.0%} of {len(cloud.points)}")
        print("  points define no plane within 2 voxels")

    judge = consensus.judge

    def traced(prepared: assessment.PreparedCheck, pose: np.ndarray) -> assessment.Assessment:
        check = judge(prepared, pose)
        turn = float(pose_errors(pose[None], truth[None])[0][0])  # shifts: in register's frame
        print(f"judged on the grid: turned {turn:.1f}° from the truth: {_words(check)}")
        return check

    consensus.judge = auto.judge = traced
    try:
        result = register(template, source)
    finally:
        consensus.judge = auto.judge = judge
    print(f"answer: {off(result.transform)}, path {np.atleast_1d(result.info['path'])[0]}")
    check = PreparedPair(template, source).check()
    for name, pose in (("truth", truth), ("answer", result.transform)):
        verdict = assessment.judge(check, pose)
        moved = transform_points(assessment._nearest_fit(check, pose), check.source_points)
        source_side = overlap_fit(check.tree, moved, check.limit)
        template_side = overlap_fit(cloud_tree(moved), check.template_points, check.limit)
        print(
            f"{name} on the clouds: {_words(verdict)}; source side {source_side[0]:.3f} "
            f"({source_side[2]:.0%} in the overlap), template side {template_side[0]:.3f} "
            f"({template_side[2]:.0%})"
        )


def _words(check) -> str:
    return (
        f"{check.verdict}, overlap fit {check.overlap_fit:.3f}, nearest fit "
        f"{check.nearby_deg:.2f}° and {check.nearby_shift:.1%} away, slide gain "
        f"{check.slide_gain:.3f}"
    )


if __name__ == "__main__":
    run_script(main)

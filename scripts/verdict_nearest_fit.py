"""The verdict's nearest fit: point-to-point ICP (the shipped one) against Open3D's
generalized ICP (plane-to-plane), at known poses.

    python scripts/verdict_nearest_fit.py [--pairs 100]
    python scripts/verdict_nearest_fit.py --density-draws 8

For each of three sets of the robust benchmark (re-sampled ModelNet40 pairs of 512 points,
scan pairs re-sampled, scan pairs sharing points; its seed 0): the verdict
(:func:`masknet.registration.assessment.judge`) at the true pose and at the true pose
turned 30 degrees, counted by verdict, with each nearest fit. A diagnostic: the generalized
ICP is swapped in for the module's own nearest fit, which it does not change. Needs
Open3D and the ModelNet40 data (``--data`` or ``$MASKNET_DATA``).

With ``--density-draws N``: instead, ``scripts/density_draws.py``'s table for the 3DMatch
pair at 2,000 and 5,000 source points and the room scans at 5,000, N draws each, with the
generalized ICP as the verdict's nearest fit (the default's consensus front end and the
table's verdict column both use it).
"""

from __future__ import annotations

import argparse
import collections
import sys
import warnings
from pathlib import Path

import numpy as np

from masknet.cli import run_script

TURN_DEG = 30.0


def generalized_icp_nearest_fit(prepared, transform: np.ndarray) -> np.ndarray:
    """The pose (4, 4) Open3D's generalized ICP reaches from ``transform`` (4, 4) with the
    shipped nearest fit's cut-off, iterations and unit-free stopping rule."""
    from masknet.geometry.open3d_clouds import to_open3d
    from masknet.io import require_open3d
    from masknet.registration import assessment

    reg = require_open3d("the generalized ICP").pipelines.registration
    found = reg.registration_generalized_icp(
        to_open3d(np.asarray(prepared.source_points, np.float64)),
        to_open3d(np.asarray(prepared.template, np.float64)),
        assessment.NEAR * prepared.limit,
        np.asarray(transform, np.float64),
        reg.TransformationEstimationForGeneralizedICP(),
        reg.ICPConvergenceCriteria(
            relative_fitness=1e-6,
            relative_rmse=1e-6 * prepared.limit,
            max_iteration=assessment.NEAR_ITERATIONS,
        ),
    )
    return np.asarray(found.transformation)


def main() -> None:
    from scipy.spatial.transform import Rotation

    from masknet.evaluation.registration import pair_arrays
    from masknet.experiments import robust
    from masknet.experiments.context import BenchmarkContext
    from masknet.registration import assessment

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=100)
    parser.add_argument("--data", default=None, help="ModelNet40 .npz (default $MASKNET_DATA)")
    parser.add_argument("--density-draws", type=int, default=0)
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    if args.density_draws:
        _density(args.density_draws)
        return
    ctx = BenchmarkContext(data=args.data, pairs=args.pairs)
    sets = {
        "re-sampled ModelNet40": robust._resampled(ctx, args.pairs),
        "scans, re-sampled": robust._scan_pairs(ctx, args.pairs),
        "scans, shared points": robust._scan_pairs(ctx, args.pairs, shared=True),
    }
    turn = np.eye(4)
    axis = np.array([0.0, 0.6, 0.8])
    turn[:3, :3] = Rotation.from_rotvec(np.radians(TURN_DEG) * axis).as_matrix()
    fits = {
        "point-to-point (shipped)": assessment._nearest_fit,
        "generalized ICP": generalized_icp_nearest_fit,
    }
    print(f"| set | nearest fit | at the truth | {TURN_DEG:g} degrees off |")
    print("|---|---|---|---|")
    try:
        for name, pairs in sets.items():
            if pairs is None:
                continue
            templates, sources, truths = pair_arrays(pairs)
            for label, fit in fits.items():
                assessment._nearest_fit = fit
                right, off = collections.Counter(), collections.Counter()
                for template, source, truth in zip(templates, sources, truths, strict=True):
                    prepared = assessment.prepare_check(template, source, open3d=True)
                    right[assessment.judge(prepared, truth).verdict] += 1
                    off[assessment.judge(prepared, truth @ turn).verdict] += 1
                print(f"| {name} | {label} | {dict(right)} | {dict(off)} |", flush=True)
    finally:
        assessment._nearest_fit = fits["point-to-point (shipped)"]


def _density(draws: int) -> None:
    """density_draws.py's table on the sparse sets with the generalized ICP's nearest fit."""
    from masknet.registration import assessment

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import density_draws

    density_draws.SETS = {"3DMatch pair": (2000, 5000), "two room scans": (5000,)}
    shipped = assessment._nearest_fit
    assessment._nearest_fit = generalized_icp_nearest_fit
    sys.argv = [sys.argv[0], "--draws", str(draws)]
    try:
        density_draws.main()
    finally:
        assessment._nearest_fit = shipped


if __name__ == "__main__":
    run_script(main)

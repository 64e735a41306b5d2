"""The verdict's nearest fit: point-to-point ICP against Open3D's generalized ICP
(plane-to-plane, ``prepare_check(..., nearest_fit="plane")``), at known poses.

    python scripts/verdict_nearest_fit.py [--pairs 100]

For each of three sets of the robust benchmark (re-sampled ModelNet40 pairs of 512 points,
scan pairs re-sampled, scan pairs sharing points; its seed 0): the verdict
(:func:`masknet.registration.judge.assessment.judge`) at the true pose and at the true pose
turned 30 degrees, counted by verdict, with each nearest fit. The default uses the
plane-to-plane fit only in the consensus front end of scans (templates of
``consensus_from`` points or more); ``scripts/density_draws.py`` measures it there. Needs
Open3D and the ModelNet40 data (``--data`` or ``$MASKNET_DATA``).
"""

from __future__ import annotations

import argparse
import collections
import warnings

import numpy as np

from masknet.cli import run_script

TURN_DEG = 30.0


def main() -> None:
    from scipy.spatial.transform import Rotation

    from masknet.evaluation.registration import pair_arrays
    from masknet.experiments import robust
    from masknet.experiments.context import BenchmarkContext
    from masknet.registration.judge import assessment

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=100)
    parser.add_argument("--data", default=None, help="ModelNet40 .npz (default $MASKNET_DATA)")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    ctx = BenchmarkContext(data=args.data, pairs=args.pairs)
    sets = {
        "re-sampled ModelNet40": robust._resampled(ctx, args.pairs),
        "scans, re-sampled": robust._scan_pairs(ctx, args.pairs),
        "scans, shared points": robust._scan_pairs(ctx, args.pairs, shared=True),
    }
    turn = np.eye(4)
    axis = np.array([0.0, 0.6, 0.8])
    turn[:3, :3] = Rotation.from_rotvec(np.radians(TURN_DEG) * axis).as_matrix()
    fits = {"point-to-point": "point", "generalized ICP": "plane"}
    print(f"| set | nearest fit | at the truth | {TURN_DEG:g} degrees off |")
    print("|---|---|---|---|")
    for name, pairs in sets.items():
        if pairs is None:
            continue
        templates, sources, truths = pair_arrays(pairs)
        for label, fit in fits.items():
            right, off = collections.Counter(), collections.Counter()
            for template, source, truth in zip(templates, sources, truths, strict=True):
                prepared = assessment.prepare_check(template, source, nearest_fit=fit)
                right[assessment.judge(prepared, truth).verdict] += 1
                off[assessment.judge(prepared, truth @ turn).verdict] += 1
            print(f"| {name} | {label} | {dict(right)} | {dict(off)} |", flush=True)


if __name__ == "__main__":
    run_script(main)

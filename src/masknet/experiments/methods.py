"""``methods``: every method of the method table, X and Mask-X, on one real pair.

The 3DMatch pair of ../shared/data/scans (GeoTransformer's demo fragments, ground truth
given), 2,000 points drawn from each cloud (seeded), in metres. The rows are exactly the
methods of :data:`masknet.registration.terms.methods.METHOD_TABLE`, each with its defaults and
its shipped weights, so a method added to the table appears here.
"""

from __future__ import annotations

import time

import numpy as np

from masknet.evaluation.registration import pose_errors
from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.experiments.scans import THREEDMATCH_FILES, load_pair, scans_folder
from masknet.registration.terms.methods import METHOD_TABLE

__all__ = ["POINTS", "run"]

POINTS = 2000  # drawn from each cloud: every method, the networks included, runs on them


def run(ctx: BenchmarkContext) -> ExperimentResult:
    """Rotation and translation error and time of each method, with and without a mask."""
    from masknet.registration.api import register

    template, source, truth = load_pair(scans_folder(), *THREEDMATCH_FILES)
    rng = np.random.default_rng(0)
    template = template[rng.choice(len(template), POINTS, replace=False)]
    source = source[rng.choice(len(source), POINTS, replace=False)]
    register(template, source)  # warm: the weights read, the kernels chosen
    rows = []
    for name, entry in METHOD_TABLE.items():
        for use_mask in (False, True):
            tic = time.perf_counter()
            result = register(template, source, method=name, use_mask=use_mask)
            seconds = time.perf_counter() - tic
            rot, trans = pose_errors(result.transform[None], truth[None])
            rows.append(
                {
                    "method": name,
                    "pipeline": ("Mask-" if use_mask else "") + entry.title,
                    "rot_error_deg": float(rot[0]),
                    "trans_error_m": float(trans[0]),
                    "seconds": seconds,
                }
            )
    still_rot, still_trans = pose_errors(np.eye(4)[None], truth[None])
    summary = (
        f"The 3DMatch pair, {POINTS:,} points drawn from each cloud, in metres; doing nothing "
        f"is {float(still_rot[0]):.1f} degrees and {float(still_trans[0]):.2f} m off. One call "
        "per row, each method with its defaults and shipped weights (the paper's single round "
        "for the Mask-X methods)."
    )
    return ExperimentResult(rows, summary)

"""``success``: is :func:`~masknet.registration.assess_registration`'s verdict right?

Calibration poses: each pair's ground-truth pose, and that pose turned 2, 5, 15 and 45
degrees about a random axis through the moved source's centroid. Sets: ModelNet40 pairs
of the paper's protocol (clean, noise sigma 0.01, 10% outliers); pairs cut from the
evaluation scans with and without shared points; the 3DMatch pair (its ground truth) and
the two room scans (the consensus pose of the ``real-pairs`` experiment), 20 axes per
angle each.

A verdict is *right* when it is ``likely correct`` at the true pose, not ``likely wrong``
at 2 and 5 degrees, not ``likely correct`` at 15 degrees, and ``likely wrong`` at 45.
A second table judges the default's own results on pairs with ground truth: a result
within 5 degrees (and 10% of the radius) must not be called ``likely wrong``, one more
than 15 degrees off must not be called ``likely correct``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from masknet.data.pairs import PairConfig
from masknet.evaluation.registration import pose_errors
from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.experiments.scans import THREEDMATCH_FILES, load_pair, scans_folder
from masknet.geometry.clouds import centroid_radius
from masknet.registration.api import register
from masknet.registration.judge.assessment import VERDICTS, assess_registration

ANGLES = (0, 2, 5, 15, 45)


def is_right(angle: float, verdict: str) -> bool:
    """The rule of the module docstring."""
    if angle == 0:
        return verdict == "likely correct"
    if angle <= 5:
        return verdict != "likely wrong"
    if angle < 45:
        return verdict != "likely correct"
    return verdict == "likely wrong"


def turned(truth: np.ndarray, source: np.ndarray, degrees: float, rng) -> np.ndarray:
    """``truth`` (4, 4) followed by a turn of ``degrees`` about a random axis through the
    centroid of ``source`` moved by ``truth``."""
    if degrees == 0:
        return truth
    axis = rng.normal(size=3)
    rot = Rotation.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis)).as_matrix()
    centre = (source @ truth[:3, :3].T + truth[:3, 3]).mean(0)
    turn = np.eye(4)
    turn[:3, :3], turn[:3, 3] = rot, centre - rot @ centre
    return turn @ truth


def _sets(ctx: BenchmarkContext) -> dict[str, tuple[list, int]]:
    """Set name -> ([(template, source, true pose)], turns per angle)."""
    from masknet.experiments.rounds import scan_eval_pairs

    count = 8 if ctx.quick else 100
    sets = {}
    for name, config in (
        ("ModelNet40 clean", PairConfig()),
        ("ModelNet40 noise 0.01", PairConfig(noise_sigma=0.01)),
        ("ModelNet40 10% outliers", PairConfig(outlier_ratio=0.1)),
    ):
        pairs = ctx.test_pairs(config, count)
        sets[name] = (_triples(pairs), 1)
    folder = scans_folder()
    if not folder.is_dir():
        return sets
    per_scan = 1 if ctx.quick else 7
    for shared, name in ((True, "scans, shared points"), (False, "scans, re-sampled")):
        sets[name] = (_triples(scan_eval_pairs(per_scan, shared, ctx.seed)), 1)
    pair = load_pair(folder, *THREEDMATCH_FILES)
    sets["3DMatch pair"] = ([pair], 1 if ctx.quick else 20)
    if not ctx.quick:
        from masknet.experiments.real_pairs import consensus_pose

        template, source, _ = load_pair(folder, "room_scan1.pcd", "room_scan2.pcd", None)
        sets["two room scans (consensus)"] = (
            [(template, source, consensus_pose(template, source)[0])],
            20,
        )
    return sets


def _triples(pairs) -> list:
    return [
        (t.double().numpy(), s.double().numpy(), tf.double().numpy())
        for t, s, tf in zip(pairs.template, pairs.source, pairs.transform, strict=True)
    ]


def run(ctx: BenchmarkContext) -> ExperimentResult:
    """Verdicts at calibration poses per set and angle, and on the default's results."""
    rows = []
    rng = np.random.default_rng(ctx.seed)
    own = {name: [] for name in VERDICTS}
    for name, (triples, turns) in _sets(ctx).items():
        verdicts = {angle: [] for angle in ANGLES}
        for template, source, truth in triples:
            for angle in ANGLES:
                for _ in range(turns if angle else 1):
                    pose = turned(truth, source, angle, rng)
                    verdicts[angle].append(assess_registration(template, source, pose).verdict)
            if not name.startswith(("3DMatch", "two room")):
                result = register(template, source)
                rot, trans = pose_errors(result.transform[None], truth[None])
                radius = centroid_radius(template)
                good = bool(rot[0] <= 5 and trans[0] <= 0.1 * radius)
                bad = bool(rot[0] > 15)
                verdict = assess_registration(template, source, result.transform).verdict
                own[verdict].append((name, good, bad))
        for angle in ANGLES:
            got = verdicts[angle]
            rows.append(
                {
                    "table": "calibration poses",
                    "set": name,
                    "degrees_off": angle,
                    "poses": len(got),
                    **{v.replace(" ", "_"): got.count(v) for v in VERDICTS},
                    "right": float(np.mean([is_right(angle, v) for v in got])),
                }
            )
        every = [is_right(a, v) for a in ANGLES for v in verdicts[a]]
        rows.append(
            {
                "table": "calibration poses",
                "set": name,
                "degrees_off": "all",
                "poses": len(every),
                "right": float(np.mean(every)),
            }
        )
    for verdict, cases in own.items():
        rows.append(
            {
                "table": "the default's own results",
                "set": "all sets with ground truth",
                "verdict": verdict,
                "results": len(cases),
                "within_5_deg": sum(good for _, good, _ in cases),
                "over_15_deg": sum(bad for _, _, bad in cases),
            }
        )
    summary = (
        "Verdicts of assess_registration at the true pose and at poses turned 2, 5, 15 and "
        "45 degrees off it. Right: 'likely correct' at the true pose, not 'likely wrong' at "
        "2 and 5 degrees, not 'likely correct' at 15, 'likely wrong' at 45. The last rows "
        "judge the default register()'s own results on the ModelNet40 and scan pairs."
    )
    return ExperimentResult(rows, summary)

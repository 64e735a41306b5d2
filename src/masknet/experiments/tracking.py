"""``tracking``: following an object through a stream, against registering every frame.

Synthetic sequences with known truth (:mod:`masknet.tracking.sequences`): a ModelNet40
object moving on a floor among other shapes, seen by one camera, hidden behind a wall for
a few frames and jumping once. The trackers start from the first frame's true pose (a
tracker's ``init``: finding the object is the search's task, which ``register every
frame`` measures); the first frame is not scored. Three ways to follow it:

* ``track``: :func:`masknet.track` (prediction, ICP near the object, the verdict, search
  when the track slips), told the camera's position (``viewpoint``) for its searches;
* ``register every frame``: the default :func:`masknet.register` on every whole frame
  (the scene search each time), judged by :func:`masknet.assess_registration`;
* ``open3d icp from the last pose``: the loop a user writes: from the first pose,
  Open3D's point-to-point ICP of each whole frame from the last pose (pairs
  cut at a tenth of the object's radius), with no verdict.

Per method and object: the share of frames within 5 degrees and 5% of the object's radius
(every frame after the first in which the object is in view), the frames from the jump
until a pose is within those bounds again, the share of the hidden frames reported as not
trusted (``lost``, or a verdict other than ``likely correct``), the share of frames with a
trusted pose that is wrong (over twice those bounds), and the milliseconds per frame.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Iterator

import numpy as np

from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.tracking.sequences import Sequence, SequenceConfig, sequences_from_shapes

__all__ = ["METHODS", "run", "score"]

TOLERANCE_DEG, TOLERANCE_SHIFT = 5.0, 0.05  # within: degrees, and shares of the radius
# Five categories, one near-symmetric (a cup: a cylinder with a handle).
CATEGORIES = ("chair", "cup", "airplane", "toilet", "monitor", "sofa")
ICP_CUT = 0.1  # the user loop's pair cut-off, in object radii
# Floor points per frame, one per object in turn: scenes of about 3,000 to 20,000 points.
FLOOR_POINTS = (3500, 7000, 12000, 18000, 24000)

# transform (frame -> template), trusted, seconds, whether the frame counts for the median
# time (the tracker's tracked frames; every frame of the others)
Answer = tuple[np.ndarray, bool, float, bool]


def _tracker(seq: Sequence) -> Iterator[Answer]:
    from masknet.tracking import track

    viewpoint = tuple(float(v) for v in seq.viewpoint)  # the camera, known to a tracker
    for result in track(seq.template, seq.frames, init=seq.truth[0], viewpoint=viewpoint):
        trusted = result.state != "lost" and result.verdict == "likely correct"
        yield result.transform, trusted, result.seconds, result.state == "tracked"


def _register_each(seq: Sequence) -> Iterator[Answer]:
    from masknet import assess_registration, register
    from masknet.geometry.clouds import centroid_radius
    from masknet.tracking.tracker import MARGIN, MIN_NEAR
    from masknet.tracking.view import points_near

    for frame in seq.frames:
        tic = time.perf_counter()
        transform = register(seq.template, frame).transform
        seconds = time.perf_counter() - tic
        # The verdict on the frame points near the object found (timed apart: a user may
        # skip it).
        reach = MARGIN * centroid_radius(seq.template)  # as the tracker judges its poses
        near = points_near(frame, transform, seq.template.mean(0), reach)
        enough = len(near) >= MIN_NEAR
        verdict = assess_registration(seq.template, near, transform).verdict if enough else ""
        yield transform, verdict == "likely correct", seconds, True


def _icp_from_last(seq: Sequence) -> Iterator[Answer]:
    from masknet.registration.solvers.open3d_icp import open3d_icp

    pose = seq.truth[0]
    yield pose, True, 0.0, False  # the first pose, given
    for frame in seq.frames[1:]:
        tic = time.perf_counter()
        pose = open3d_icp(seq.template, frame, pose, 30, ICP_CUT * seq.radius).transform[0]
        pose = pose.numpy()
        yield pose, True, time.perf_counter() - tic, True  # no verdict: every pose is taken


METHODS: dict[str, Callable[[Sequence], Iterator[Answer]]] = {
    "track": _tracker,
    "register every frame": _register_each,
    "open3d icp from the last pose": _icp_from_last,
}


def _errors(seq: Sequence, transforms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: rotation error (degrees) and the object's centre's error over its
    radius; inf where there is no pose."""
    from masknet.geometry.se3 import rotation_angle_deg

    finite = np.isfinite(transforms).all(axis=(1, 2))
    safe = np.where(finite[:, None, None], transforms, np.eye(4))
    delta = safe @ np.linalg.inv(seq.truth)  # the identity where right
    degrees = np.asarray(rotation_angle_deg(delta[:, :3, :3]), dtype=np.float64)
    centre = np.append(seq.template.mean(0), 1)
    placed = np.linalg.solve(safe, centre)[:, :3]
    truth = np.linalg.solve(seq.truth, centre)[:, :3]
    shift = np.linalg.norm(placed - truth, axis=1) / seq.radius
    return np.where(finite, degrees, np.inf), np.where(finite, shift, np.inf)


def score(seq: Sequence, answers: list[Answer]) -> dict:
    """One row's figures for a method's ``answers`` (one per frame) on ``seq``."""
    transforms = np.stack([a[0] for a in answers])
    trusted = np.array([a[1] for a in answers])
    degrees, shift = _errors(seq, transforms)
    within = (degrees <= TOLERANCE_DEG) & (shift <= TOLERANCE_SHIFT)
    wrong = (degrees > 2 * TOLERANCE_DEG) | (shift > 2 * TOLERANCE_SHIFT)
    later = np.arange(len(answers)) > 0
    row = {
        "within": float(within[later & ~seq.occluded].mean()),
        "frames_to_refind": None,
        "hidden_not_trusted": float((~trusted[seq.occluded]).mean())
        if seq.occluded.any()
        else None,
        "trusted_wrong": float((trusted & wrong)[later].mean()),
        "ms_per_frame": 1000 * float(np.mean([a[2] for a in answers])),
        "median_ms": 1000 * float(np.median([a[2] for a in answers if a[3]] or [np.nan])),
        "scene_points": [min(len(f) for f in seq.frames), max(len(f) for f in seq.frames)],
    }
    if seq.jump is not None:
        back = np.flatnonzero(within[seq.jump :] & trusted[seq.jump :])
        row["frames_to_refind"] = int(back[0]) if len(back) else None
    return row


def _objects(ctx: BenchmarkContext, count: int) -> list[int]:
    """The first test shape of each of the first ``count`` categories of
    :data:`CATEGORIES` that the set holds."""
    names, labels = list(ctx.test_set.shape_names), ctx.categories
    out = []
    for category in CATEGORIES:
        if category in names:
            hits = np.flatnonzero(labels == names.index(category))
            if len(hits):
                out.append(int(hits[0]))
    return out[:count]


def run(ctx: BenchmarkContext) -> ExperimentResult:
    """Every method on every sequence: one row per method and object. Five objects of 100
    frames; ``--quick`` two of 60; ``--pairs N`` at most 3N frames each."""
    count, frames = (2, 60) if ctx.quick else (5, 100)
    frames = min(frames, max(12, 3 * ctx.pairs))  # --pairs N: at most 3N frames (smoke runs)
    objects = _objects(ctx, count)
    hidden = min(8, max(2, frames // 7))
    names = [str(n) for n in ctx.test_set.names]
    sequences = []
    for n, index in enumerate(objects):  # each its own floor density (FLOOR_POINTS)
        config = SequenceConfig(frames, occlusion_frames=hidden, floor_points=FLOOR_POINTS[n])
        sequences += sequences_from_shapes(ctx.points, names, [index], config, ctx.seed + n)
    rows = []
    for seq in sequences:
        for method, answers_of in METHODS.items():

            def compute(seq=seq, answers_of=answers_of) -> dict:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # the sequences' few-point warnings
                    return score(seq, list(answers_of(seq)))

            key = {"object": seq.name, "method": method, "frames": frames}
            rows.append(ctx.row(key, compute))
    summary = (
        f"{len(sequences)} synthetic sequences of {frames} frames (a ModelNet40 object on a "
        f"floor of {', '.join(f'{p:,}' for p in FLOOR_POINTS[: len(objects)])} points, "
        f"among {config.clutter} other shapes, one camera, hidden for "
        f"{config.occlusion_frames} frames, a jump of {config.jump_deg:.0f} degrees and "
        f"{config.jump_shift:.0%} of its radius at frame {config.jump_frame}; the trackers "
        "start from the first frame's true pose). within: the "
        f"share of frames after the first, the object in view, within {TOLERANCE_DEG:.0f} "
        f"degrees and {TOLERANCE_SHIFT:.0%} of its radius; frames_to_refind: from the jump "
        "to the first trusted pose within them (None: never); hidden_not_trusted: the "
        "share of hidden frames reported lost or not likely correct (the ICP loop has no "
        "verdict); trusted_wrong: frames whose trusted pose is over twice the bounds off; "
        "ms_per_frame: mean wall time; median_ms: the median over the tracker's tracked "
        "frames and every frame of the others (the ICP loop's after the first); "
        "scene_points: the fewest and most points of a frame. Times are not comparable "
        "across machines."
    )
    return ExperimentResult(rows, summary)

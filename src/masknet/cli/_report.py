"""What ``masknet register`` prints about a result: the path the default took and why, and
the numbers the method reported."""

from __future__ import annotations

import sys

import numpy as np

__all__ = ["print_result", "report_path", "shown_numbers"]

# Below this fraction of the template on the scan where a scene search found it, the CLI
# warns that the object may not be in the scan.
LOW_FITNESS = 0.5


def shown_numbers(info: dict) -> str:
    """The method's scalar numbers as a reader expects them (NaN marks what did not happen,
    no runner-up, no escalation: left out)."""
    numbers = {
        k: v
        for k, v in info.items()
        if np.ndim(v) == 0 and _is_number(v) and not np.isnan(np.asarray(v, np.float64))
    }
    return ", ".join(f"{k} {_shown(v)}" for k, v in numbers.items())


def _shown(value: object) -> str:
    """A reported number as a reader expects it: True/False for flags, 4 digits else."""
    item = np.asarray(value).item()
    return str(item) if isinstance(item, bool) else f"{item:.4g}"


def _is_number(value: object) -> bool:
    return np.issubdtype(np.asarray(value).dtype, np.number) or np.asarray(value).dtype == bool


def report_path(info: dict, rotation: np.ndarray, source_name: str = "the source") -> None:
    """Say which path of ``auto`` / ``robust`` ran and why, and warn of an ambiguous answer
    (``rotation``: the result's (3, 3); ``source_name``: the source file's name)."""
    if "path" not in info:
        return
    path = str(info["path"])
    escalated = float(info.get("escalated_fitness", np.nan))
    if path == "scene search":
        print(f"path: scene search (the template found in {source_name}, then Mask-ICP from there)")
        return
    if path == "fast" and np.isnan(escalated):
        why = "the fast path's fit passed"
    elif path == "fast":
        why = f"escalated (fit {escalated:.3f}), but the fast path's pose fitted best"
    elif path == "robust/consensus" and np.isfinite(escalated):
        why = (
            f"escalated (the fast path's fit was {escalated:.3f}); the front end's uncertain "
            "pose ranked above the search's answer"
        )
    elif np.isfinite(escalated):
        why = f"escalated: the fast path's fit was {escalated:.3f}"
    elif path == "consensus":
        why = "the consensus front end, first for scans and sparse clouds, judged it likely correct"
    elif path.startswith("robust/"):
        why = "the search first: the source's principal axes are turned far from the template's"
    else:
        why = "method robust"
    print(f"path: {path} ({why}); best hypothesis from {info['source']}")
    if bool(info.get("ambiguous", False)):
        from masknet.registration.judge.hypotheses import rotation_between_deg

        result_pose = np.eye(4)
        result_pose[:3, :3] = rotation
        apart = rotation_between_deg(np.asarray(info["runner_up"]), result_pose)
        print(
            "masknet: warning: the answer is ambiguous: another pose fits as well (score "
            f"{float(info['runner_up_score']):.3f} against {float(info['score']):.3f}; its "
            f"rotation is {apart:.1f} deg from this one); the "
            "shape "
            "may be symmetric",
            file=sys.stderr,
        )


def print_result(args, name: str, template, source, source_rows, result) -> None:
    """What ran and what it found: sizes, masks, the scene search, the rounds' moves and the
    estimated motion (``source_rows``: the file's rows kept, for the dropped count)."""
    n, m = result.sampled
    sampled = "" if (n, m) == (len(template), len(source)) else f" (sampled to {n} and {m})"
    if sampled and "path" in result.info:  # auto and robust: only the networks see samples
        sampled = f" (the networks see {n:,} and {m:,} sampled points)"
    dropped = len(source_rows) - len(source)
    dropped_text = f", {dropped:,} non-finite rows dropped" if dropped else ""
    loop = ""
    if args.iterations > 1 and not args.no_mask:
        from masknet.registration.stages.refinement import DEFAULT_REFINER

        refine = args.refine_masks or DEFAULT_REFINER
        loop = f"; {args.iterations} rounds, masks of rounds >= 2: {refine}"
    print(
        f"{name}: template {len(template):,} points, source {len(source):,}{sampled}{dropped_text}"
        f"{loop}"
    )
    if result.mask is not None:
        print(f"inliers: {int(result.mask.sum()):,} of {len(template):,} template points")
    if result.scene is not None:
        from pathlib import Path

        template_name, source_name = Path(args.template).name, Path(args.source).name
        print(
            f"scene search: {result.scene.regions} regions of {source_name} searched, "
            f"{result.scene.spacing:.2g} template radii apart, "
            f"in {result.times['search']:.1f} s; {100 * result.scene.coverage:.1f}% "
            "of the template lies on the scene where it was found"
        )
        if result.scene.coverage < LOW_FITNESS:
            print(
                f"masknet: warning: under half of {template_name} lies on {source_name} where "
                f"it fits best; the object may not be in this scan (or {template_name} shows "
                "more of it than the scan sees)",
                file=sys.stderr,
            )
    if result.source_mask is not None:
        print(f"source kept: {int(result.source_mask.sum()):,} of {len(source):,} points")
    if len(result.rounds) > 1:  # how far each round moved the source: has the loop settled?
        from masknet.geometry.se3 import transform_points
        from masknet.registration.judge.hypotheses import rotation_between_deg

        steps = []
        for r, (before, after) in enumerate(zip(result.rounds, result.rounds[1:], strict=False), 2):
            shift = np.linalg.norm(
                transform_points(after, source) - transform_points(before, source), axis=-1
            )
            steps.append(
                f"round {r} {rotation_between_deg(before, after):.3f} deg, "
                f"median point {np.median(shift):.3g}"
            )
        print("rounds moved the source: " + "; ".join(steps) + " (input units)")
    angle = float(result.rotation_deg)
    print(
        f"estimated motion: rotation {angle:.2f} deg, translation {np.linalg.norm(result.t):.4g} "
        f"(input units); {1e3 * result.times['total']:.1f} ms"
    )

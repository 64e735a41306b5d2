"""What ``masknet register`` prints about a result: the path the default took and why, and
the numbers the method reported."""

from __future__ import annotations

import sys

import numpy as np

__all__ = ["report_path", "shown_numbers"]


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


def report_path(info: dict, rotation: np.ndarray) -> None:
    """Say which path of ``auto`` / ``robust`` ran and why, and warn of an ambiguous answer
    (``rotation``: the result's (3, 3))."""
    if "path" not in info:
        return
    path = str(info["path"])
    escalated = float(info.get("escalated_fitness", np.nan))
    if path == "scene search":
        print("path: scene search (the template found in SOURCE, then Mask-ICP from there)")
        return
    if path == "fast" and np.isnan(escalated):
        why = "the fast path's fit passed"
    elif path == "fast":
        why = f"escalated (fit {escalated:.3f}), but the fast path's pose fitted best"
    elif np.isfinite(escalated):
        why = f"escalated: the fast path's fit was {escalated:.3f}"
    else:
        why = "method robust"
    print(f"path: {path} ({why}); best hypothesis from {info['source']}")
    if bool(info.get("ambiguous", False)):
        from masknet.registration.hypotheses import rotation_between_deg

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

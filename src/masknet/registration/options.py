"""Typed options of :func:`masknet.register`, in the style of Open3D's
``ICPConvergenceCriteria``: small immutable objects that name what they set.

    >>> register(template, source, rounds=Rounds(3, refine=10), selection=Selection(threshold=0.5))
    >>> register(template, source, criteria=ICPCriteria(max_iterations=30))
    >>> register(template, source, method="robust", robust=RobustOptions(hypotheses=12))

Each is the same as the keyword arguments it replaces (``iterations`` and
``refine_iterations``; ``k`` and ``threshold``; the ICP options); giving both is an error.
"""

from __future__ import annotations

from typing import NamedTuple

from masknet.errors import MaskNetError
from masknet.registration.robust import RobustOptions

__all__ = ["ICPCriteria", "Rounds", "RobustOptions", "Selection", "resolve_options"]


class ICPCriteria(NamedTuple):
    """ICP's budget and rules (``method="icp"``).

    max_iterations: updates per round. tolerance: stop once the mean squared error
    changes by at most this fraction of itself. max_correspondence_distance: pairs
    farther apart (in the clouds' units) are not used; None keeps all.
    """

    max_iterations: int = 10
    tolerance: float = 1e-6
    max_correspondence_distance: float | None = None


class Selection(NamedTuple):
    """Which template points the mask keeps: top-``k`` (default k = M, the number of
    source points) or scores >= ``threshold``; at most one of the two."""

    k: int | None = None
    threshold: float | None = None


class Rounds(NamedTuple):
    """``n`` rounds of {mask -> initialise -> register -> move the source}, then
    ``refine`` iterations of plain ICP against the whole template."""

    n: int = 1
    refine: int = 0


def resolve_options(
    method: str,
    keywords: dict,
    criteria: ICPCriteria | None,
    selection: Selection | None,
    rounds: Rounds | None,
    robust: RobustOptions | None,
) -> dict:
    """``keywords`` (register's iterations, refine_iterations, k, threshold and
    **options) with the typed objects merged in; MaskNetError where both set a value."""
    for name, obj, kind in (
        ("criteria", criteria, ICPCriteria),
        ("selection", selection, Selection),
        ("rounds", rounds, Rounds),
        ("robust", robust, RobustOptions),
    ):
        if obj is not None and not isinstance(obj, kind):
            raise MaskNetError(
                f"{name}= takes a {kind.__name__}, got {type(obj).__name__}"
                + (" (for a number of rounds, pass iterations=)" if name == "rounds" else "")
            )
    out = dict(keywords)

    def merge(obj: NamedTuple | None, names: dict[str, str], defaults: dict) -> None:
        if obj is None:
            return
        for field, key in names.items():
            if key in out and out[key] != defaults.get(key):
                raise MaskNetError(f"give {key}= or {type(obj).__name__}, not both")
            out[key] = getattr(obj, field)

    defaults = {"iterations": 1, "refine_iterations": 0, "k": None, "threshold": None}
    merge(rounds, {"n": "iterations", "refine": "refine_iterations"}, defaults)
    merge(selection, {"k": "k", "threshold": "threshold"}, defaults)
    if criteria is not None:
        if method != "icp":
            raise MaskNetError(f"criteria= (ICPCriteria) is for method='icp', not {method!r}")
        merge(criteria, {f: f for f in ICPCriteria._fields}, {})
    if robust is not None:
        if method != "robust":
            raise MaskNetError(f"robust= (RobustOptions) is for method='robust', not {method!r}")
        merge(robust, {f: f for f in RobustOptions._fields}, {})
    return out

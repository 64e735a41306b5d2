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


class RobustOptions(NamedTuple):
    """The options of ``method="robust"`` (``register(..., method="robust", **options)``).

    hypotheses: starting rotations per pair (1-24 take the 24 cube rotations nearest
        the identity first; more add seeded random rotations).
    hypothesis_points: points per cloud in the hypothesis stage.
    candidates: best-scoring hypotheses per pair taken on to full resolution.
    identity_margin: a turned hypothesis wins over the unturned start only if its score
        is below this fraction of the start's (1: plain best score; 0: never turn).
    hypothesis_mask: use the mask in the hypothesis stage too (False: plain ICP there,
        faster; the mask then enters at full resolution).
    mask_rounds: Mask-ICP rounds per hypothesis, and again at full resolution.
    max_iterations: ICP iterations per round.
    trim: fraction of points whose distances make the score.
    inlier_iterations: iterations of the final geometric-inlier ICP (0 skips it).
    inlier_distance: its pair cut-off, in template radii.
    """

    hypotheses: int = 24
    hypothesis_points: int = 256
    candidates: int = 6
    hypothesis_mask: bool = False
    identity_margin: float = 0.5
    mask_rounds: int = 2
    max_iterations: int = 10
    trim: float = 0.8
    inlier_iterations: int = 30
    inlier_distance: float = 0.05

    def check(self) -> None:
        """Raise MaskNetError for an option out of range."""
        if self.hypotheses < 1 or self.hypothesis_points < 16 or self.mask_rounds < 1:
            raise MaskNetError("robust: hypotheses >= 1, hypothesis_points >= 16, mask_rounds >= 1")
        if self.candidates < 1:
            raise MaskNetError("robust: candidates >= 1")
        if self.max_iterations < 1 or self.inlier_iterations < 0:
            raise MaskNetError("robust: max_iterations >= 1 and inlier_iterations >= 0")
        if not 0 <= self.identity_margin <= 1:
            raise MaskNetError("robust: identity_margin must be in [0, 1]")
        if not 0 < self.trim <= 1 or not self.inlier_distance > 0:
            raise MaskNetError("robust: trim must be in (0, 1] and inlier_distance positive")


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

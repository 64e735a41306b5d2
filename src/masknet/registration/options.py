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
    """The options of ``method="robust"`` (``register(..., method="robust", **options)``),
    the coarse-to-fine pipeline of :mod:`masknet.registration.coarse`.

    feature_points: template points left by each FPFH voxel grid, finest first (the counts
        set the voxels, so the unit does not matter; a template of N > 1,024 points gets
        sqrt(N / 1,024) times as many, at most 8 times). A fine grid matches shared points
        exactly; a coarse one is steadier where the clouds were sampled apart.
    ransac_trials: minimal samples of 3 matches per RANSAC run.
    correspondence_hypotheses: distinct poses each RANSAC run returns.
    accept_fitness: stop after the correspondence hypotheses when the best one's fitness
        (at 1.5 template spacings) reaches this; 1.01 never stops early.
    hypotheses: starting rotations of the learned side (the 24 rotations of the cube,
        nearest the identity first; 0 skips them).
    hypothesis_points: points per cloud in the rotation hypotheses' ICP.
    max_iterations: ICP iterations per hypothesis.
    candidates: best-scoring distinct hypotheses refined at full resolution.
    inlier_iterations: ICP iterations of that refinement.
    inlier_distance: its pair cut-off, in template spacings.
    fine_points: source points (a seeded random subset of larger clouds) in the fit and
        the ICP refinement; the features see every point.
    distinct_deg: poses at least this far apart are different answers.
    ambiguity_margin: a different answer whose fitness is within this of the best makes
        the result ``ambiguous``.
    """

    feature_points: tuple[int, ...] = (1000, 300)
    ransac_trials: int = 3000
    correspondence_hypotheses: int = 8
    accept_fitness: float = 0.99
    hypotheses: int = 24
    hypothesis_points: int = 128
    max_iterations: int = 8
    candidates: int = 3
    inlier_iterations: int = 60
    inlier_distance: float = 1.5
    fine_points: int = 4096
    distinct_deg: float = 10.0
    ambiguity_margin: float = 0.02

    def check(self) -> None:
        """Raise MaskNetError for an option out of range."""
        grids = tuple(self.feature_points)
        if not grids or min(*grids, self.hypothesis_points, self.fine_points) < 16:
            raise MaskNetError(
                "robust: feature_points, hypothesis_points and fine_points must be >= 16"
            )
        if self.ransac_trials < 1 or self.correspondence_hypotheses < 0:
            raise MaskNetError("robust: ransac_trials >= 1, correspondence_hypotheses >= 0")
        if not 0 <= self.hypotheses <= 24:
            raise MaskNetError("robust: hypotheses must be in [0, 24]")
        if self.candidates < 1 or self.max_iterations < 1 or self.inlier_iterations < 0:
            raise MaskNetError(
                "robust: candidates >= 1, max_iterations >= 1 and inlier_iterations >= 0"
            )
        if not 0 <= self.accept_fitness <= 1.01 or not 0 <= self.ambiguity_margin <= 1:
            raise MaskNetError("robust: accept_fitness in [0, 1.01], ambiguity_margin in [0, 1]")
        if not self.inlier_distance > 0 or not 0 < self.distinct_deg <= 180:
            raise MaskNetError("robust: inlier_distance > 0 and distinct_deg in (0, 180]")


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
        if method not in ("auto", "robust"):
            raise MaskNetError(
                f"robust= (RobustOptions) is for method='auto' or 'robust', not {method!r}"
            )
        merge(robust, {f: f for f in RobustOptions._fields}, {})
    return out

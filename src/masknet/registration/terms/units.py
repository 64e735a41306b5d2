"""Mixed units: a template in metres and a source in millimetres, said in one line before
any work.

A unit mismatch scales **both** of a cloud's lengths by the same factor: its extent (the
median distance of its points from their median point, :func:`median_spread`) and its
point spacing (:func:`median_spacing`). Each alone differs legitimately between the two
clouds of a right pair: a scene is 10-15 times an object's extent at the same spacing (the
carton in its Kinect scene), and a scan subsampled 8 times has about 2.5 times the spacing
at the same extent. Measured on the real pairs of ``../shared/data/scans`` (the 3DMatch
pair in two versions, the room scans, the carton in its scene, each also with one side
subsampled 8 times), the spacing ratio stays within 0.41-2.5 and never moves with the
extent ratio; a mixed-unit pair moves both by its factor (docs/RESULTS.md, "Mixed units").

The rule: the extents differ by at least :data:`UNIT_RATIO` and the spacings by at least
:data:`SPACING_RATIO`, **in the same direction**. What no rule of lengths can see: a scene in a unit 10 times smaller
than its object's, whose extent then matches the object's (a dense model against a sparse
scan looks the same). What it calls mixed wrongly: a densely sampled model in a much sparser
scene (spacings 6 or more times apart and extents 4 or more): the line then says "if their
units differ", and nothing else changes.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from masknet.errors import warn
from masknet.geometry.clouds import median_spacing, median_spread

__all__ = ["SPACING_RATIO", "UNIT_RATIO", "UnitCheck", "check_units", "warn_mixed_units"]

# The extents this many times apart, and the spacings SPACING_RATIO times, the same way
# round: not one unit. Real pairs: a scene's extent 4.3 times its object's at the same
# spacing; one side subsampled 8 times, spacings up to 3.5 times apart; mixed units by 10,
# both 9.4 times or more.
UNIT_RATIO = 4.0
SPACING_RATIO = 6.0
# The larger cloud is measured on at most this many points, the other on the same share of
# its own (a random subset of both by one fraction keeps the ratio of their spacings).
UNIT_POINTS = 4096
SPACING_QUERIES = 256


class UnitCheck(NamedTuple):
    """How the source's lengths compare with the template's.

    extent_ratio, spacing_ratio: source / template (the spacing ratio NaN where the extents
    did not call for it). factor: the power of ten nearest the
    spacing ratio (the likely unit factor, source / template). mixed: whether the rule
    calls the units mixed. message: one line naming the factor, or "" when not mixed.
    """

    extent_ratio: float
    spacing_ratio: float
    factor: float
    mixed: bool
    message: str


def check_units(template: np.ndarray, source: np.ndarray) -> UnitCheck:
    """Compare the lengths of template (N, 3) and source (M, 3), finite float arrays. The
    spacings are measured only where the extents already differ by :data:`UNIT_RATIO`, so
    the common case costs two medians."""
    extent = median_spread(_strided(source)) / max(median_spread(_strided(template)), 1e-300)
    if 1 / UNIT_RATIO < extent < UNIT_RATIO or not np.isfinite(extent) or extent == 0:
        return UnitCheck(extent, math.nan, 1.0, False, "")
    template, source = _same_fraction(template, source)
    spacing_t = median_spacing(template, sample=SPACING_QUERIES)
    spacing_s = median_spacing(source, sample=SPACING_QUERIES)
    if min(spacing_t, spacing_s) <= 0:
        return UnitCheck(extent, math.nan, 1.0, False, "")
    spacing = spacing_s / spacing_t
    mixed = (extent >= UNIT_RATIO and spacing >= SPACING_RATIO) or (
        extent <= 1 / UNIT_RATIO and spacing <= 1 / SPACING_RATIO
    )
    factor = 10.0 ** round(math.log10(spacing))
    message = ""
    if mixed:
        larger, times = ("source", factor) if factor >= 1 else ("template", 1 / factor)
        message = (
            f"the clouds look like different units: the {larger}'s point spacing is "
            f"{max(spacing, 1 / spacing):,.0f} times the other's and its extent "
            f"{max(extent, 1 / extent):,.3g} times (about {times:,.0f}x: millimetres against "
            "metres?); if their units differ, scale one cloud to the other's, or the result "
            "will be wrong"
        )
    return UnitCheck(extent, spacing, factor, mixed, message)


def warn_mixed_units(template: np.ndarray, source: np.ndarray) -> UnitCheck:
    """:func:`check_units`, with its line as a :class:`MaskNetWarning` when mixed."""
    check = check_units(template, source)
    if check.mixed:
        warn(check.message)
    return check


def _same_fraction(template: np.ndarray, source: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both clouds as float64, each cut to the same seeded random fraction of itself so
    that the larger has at most :data:`UNIT_POINTS` points."""
    template = np.asarray(template, dtype=np.float64)
    source = np.asarray(source, dtype=np.float64)
    fraction = min(1.0, UNIT_POINTS / max(len(template), len(source)))
    if fraction == 1.0:
        return template, source
    rng = np.random.default_rng(0)
    return tuple(  # type: ignore[return-value]
        cloud[rng.permutation(len(cloud))[: max(8, round(fraction * len(cloud)))]]
        for cloud in (template, source)
    )


def _strided(points: np.ndarray) -> np.ndarray:
    """At most about :data:`UNIT_POINTS` points, every k-th, as float64 (for medians)."""
    points = np.asarray(points, dtype=np.float64)
    return points[:: max(1, len(points) // UNIT_POINTS)]

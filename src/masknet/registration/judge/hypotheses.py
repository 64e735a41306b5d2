"""The angle between two poses. Scored hypotheses, their ranking and one per basin moved to
:mod:`masknet.registration.judge.arbiter` (:class:`~masknet.registration.judge.arbiter.Candidate`,
:func:`~masknet.registration.judge.arbiter.rank`,
:func:`~masknet.registration.judge.arbiter.one_per_basin`); the old names work for one more
release, with a ``DeprecationWarning``."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from masknet.geometry.se3 import rotation_angle_deg

__all__ = ["rotation_between_deg"]


def rotation_between_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle in degrees between the rotations of transforms ``a`` and ``b`` (4, 4)."""
    return float(rotation_angle_deg(a[:3, :3].T @ b[:3, :3]))


def _scored(fitness: float, rmse: float, score: float, pose: np.ndarray, kind: str) -> Any:
    """The former ``Scored(fitness, rmse, score, pose, kind)``: a :class:`Candidate`."""
    from masknet.registration.judge.arbiter import Candidate
    from masknet.registration.judge.fit import PoseFit

    return Candidate(pose, kind, PoseFit(fitness, rmse, score))


# Old name -> (its new spelling, the object that answers it).
_MOVED = {
    "Scored": ("masknet.registration.judge.arbiter.Candidate(pose, stage, fit)", lambda: _scored),
    "rank": ("masknet.registration.judge.arbiter.rank", lambda: _arbiter().rank),
    "distinct": (
        "masknet.registration.judge.arbiter.one_per_basin",
        lambda: _arbiter().one_per_basin,
    ),
}


def _arbiter() -> Any:
    from masknet.registration.judge import arbiter

    return arbiter


def __getattr__(name: str) -> Any:
    if name not in _MOVED:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    new, value = _MOVED[name]
    warnings.warn(
        f"{__name__}.{name} has moved to {new}; use that (the old name goes in the next release)",
        DeprecationWarning,
        stacklevel=2,
    )
    return value()

"""Scored pose hypotheses of a global search: their fit, their ranking, and one per basin."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from masknet.geometry.se3 import rotation_angle_deg

__all__ = ["Scored", "distinct", "rank", "rotation_between_deg"]


def rotation_between_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle in degrees between the rotations of transforms ``a`` and ``b`` (4, 4)."""
    return float(rotation_angle_deg(a[:3, :3].T @ b[:3, :3]))


class Scored(NamedTuple):
    """A hypothesis: its fit (:class:`PoseFit`), pose (4, 4), and where it came from."""

    fitness: float
    rmse: float
    score: float
    pose: np.ndarray
    kind: str


def rank(entry: Scored) -> tuple[float, float, float]:
    """Higher score first, then fitness, then lower RMSE."""
    return entry.score, entry.fitness, -entry.rmse


def distinct(scored: list, count: int, limit: float, degrees: float = 2.0) -> list:
    """The first ``count`` entries of ``scored`` (best first) whose poses differ from every
    earlier one kept by ``degrees`` or ``limit`` of translation: the same basin once."""
    out: list = []
    for entry in scored:
        if len(out) == count:
            break
        if all(
            rotation_between_deg(entry.pose, other.pose) >= degrees
            or np.linalg.norm(entry.pose[:3, 3] - other.pose[:3, 3]) >= limit
            for other in out
        ):
            out.append(entry)
    return out

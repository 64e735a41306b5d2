"""Pairs as a registration round leaves them: the source moved onto the template by the
true pose, then off it again by a random *residual* pose.

The refinement mask (:mod:`masknet.models.refine`) runs in rounds >= 2 of the
iterative loop, on clouds that round 1 has already brought close. It is trained on
the residuals that round 1 really leaves (round 1 of ``masknet benchmark
masks-per-round``: a median of a few degrees, a 90th percentile near 20 degrees, on
ModelNet40 and on real-scan pairs). :class:`ResidualConfig` draws from a wider mixture,
up to 45 degrees, so that a bad first round does not meet a pair it has never seen.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import Tensor

from masknet.data.pairs import Pairs
from masknet.geometry.se3 import invert_transform, make_transform, so3_exp, transform_points

__all__ = ["ResidualConfig", "residual_pairs", "turned_pairs"]


@dataclass(frozen=True)
class ResidualConfig:
    """The residual pose's distribution, for clouds of unit template radius.

    The rotation angle is drawn from a mixture: ``near_fraction`` of the pairs uniform in
    [0, ``near_deg``] (a round that converged), ``wide_fraction`` uniform in [0,
    ``max_deg``] (a round that failed), the rest half-normal with scale ``scale_deg``
    (clipped at ``max_deg``). The axis is uniform. The translation has a uniform direction
    and a half-normal length of scale ``translation + translation_per_deg * angle``,
    clipped at ``max_translation``.
    """

    near_fraction: float = 0.3
    near_deg: float = 3.0
    wide_fraction: float = 0.2
    max_deg: float = 45.0
    scale_deg: float = 12.0
    translation: float = 0.03
    translation_per_deg: float = 0.008
    max_translation: float = 0.6

    def __post_init__(self) -> None:
        if not 0 <= self.near_fraction + self.wide_fraction <= 1:
            raise ValueError("near_fraction + wide_fraction must lie in [0, 1]")
        if min(self.near_deg, self.max_deg, self.scale_deg) < 0 or self.max_deg > 180:
            raise ValueError("angles must be >= 0 and max_deg <= 180")
        if min(self.translation, self.translation_per_deg, self.max_translation) < 0:
            raise ValueError("translations must be >= 0")

    def to_dict(self) -> dict:
        return asdict(self)


def _angles_deg(b: int, config: ResidualConfig, generator: torch.Generator) -> Tensor:
    """(B,) residual angles in degrees, from the mixture of :class:`ResidualConfig`."""
    pick = torch.rand(b, generator=generator, dtype=torch.float64)
    u = torch.rand(b, generator=generator, dtype=torch.float64)
    normal = torch.randn(b, generator=generator, dtype=torch.float64).abs() * config.scale_deg
    near = pick < config.near_fraction
    wide = (pick >= config.near_fraction) & (pick < config.near_fraction + config.wide_fraction)
    angle = torch.where(near, u * config.near_deg, normal.clamp(max=config.max_deg))
    return torch.where(wide, u * config.max_deg, angle)


def residual_pairs(pairs: Pairs, config: ResidualConfig, generator: torch.Generator) -> Pairs:
    """``pairs`` with each source moved into the template frame by its true pose and then
    by a random residual pose about its own centroid.

    Args:
        pairs: template (B, N, 3), source (B, M, 3) in the source frame, ``transform``
            (B, 4, 4) the truth, source -> template, clouds of about unit radius.
        config: the residual's distribution.
        generator: seeded; the same seed gives the same residuals.

    Returns:
        Pairs whose ``source`` (B, M, 3) lies near the template and whose ``transform``
        (B, 4, 4) is what remains to be found (the residual's inverse). Masks and template
        unchanged.
    """
    b = pairs.source.shape[0]
    # (the order of the draws is the shipped refinemask_scans training's)
    axis = _unit(b, generator)
    angle = _angles_deg(b, config, generator)
    rotation = so3_exp(axis * torch.deg2rad(angle)[:, None])
    direction = _unit(b, generator)
    scale = config.translation + config.translation_per_deg * angle
    length = (torch.randn(b, generator=generator, dtype=torch.float64).abs() * scale).clamp(
        max=config.max_translation
    )
    return _moved_off(pairs, rotation, direction * length[:, None])


def turned_pairs(pairs: Pairs, angle_deg: float, generator: torch.Generator) -> Pairs:
    """``pairs`` with each source moved onto its template by the true pose, then turned by
    exactly ``angle_deg`` about a random axis through its centroid (no translation); the
    fixed residuals of the refinement-mask experiments. Fields as :func:`residual_pairs`."""
    b = pairs.source.shape[0]
    rotation = so3_exp(_unit(b, generator) * torch.deg2rad(torch.tensor(float(angle_deg))))
    return _moved_off(pairs, rotation, torch.zeros(b, 3, dtype=torch.float64))


def _unit(b: int, generator: torch.Generator) -> Tensor:
    """(B, 3) uniform random unit vectors."""
    v = torch.randn(b, 3, generator=generator, dtype=torch.float64)
    return v / v.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def _moved_off(pairs: Pairs, rotation: Tensor, offset: Tensor) -> Pairs:
    """The sources aligned by the true pose, then turned by ``rotation`` (B, 3, 3) about
    their centroids and shifted by ``offset`` (B, 3); the transform left to find."""
    aligned = transform_points(pairs.transform.double(), pairs.source.double())
    centre = aligned.mean(dim=1)  # (B, 3): turn about the source's own centroid
    shift = centre - (rotation @ centre[..., None])[..., 0] + offset
    residual = make_transform(rotation, shift)
    moved = transform_points(residual, aligned)
    return Pairs(
        pairs.template,
        moved.to(pairs.source.dtype),
        pairs.mask,
        invert_transform(residual).to(pairs.transform.dtype),
        pairs.source_mask,
    )

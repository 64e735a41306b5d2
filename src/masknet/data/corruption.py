"""Outliers, noise and clutter put into the *source* of existing pairs, labelled in
``source_mask`` (False for every point that is not the template's object).

Used to train and evaluate the two-sided MaskNet. The number of source points stays
the same: a corrupted point replaces a real one, so a batch keeps one shape, while each
pair draws its own amounts.

* **Outliers**: a fraction drawn uniformly from [0, ``max_outlier_ratio``] of the
  source, uniform in the source's bounding box grown by 10% (the paper's outliers).
* **Noise**: Gaussian, sigma drawn uniformly from [0, ``max_noise``] (in units of the
  clouds, unit radius for normalised pairs), clipped at 3 sigma, on the real points.
* **Clutter**: with probability ``clutter_probability``, a fraction in
  [``min_clutter``, ``max_clutter``] of the source becomes points of *another* cloud of
  the batch (a different object or scene crop), rotated at random, scaled by 0.5-1 and
  set beside the object at 1.2-2 of the source's radius.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import Tensor

from masknet.data.pairs import Pairs, uniform_outliers
from masknet.geometry import random_rotation
from masknet.geometry.clouds import centroid_radius

__all__ = ["CorruptionConfig", "corrupt_source"]


@dataclass(frozen=True)
class CorruptionConfig:
    """How much of the source is corrupted (see the module docstring)."""

    max_outlier_ratio: float = 0.2
    max_noise: float = 0.01
    clutter_probability: float = 0.25
    min_clutter: float = 0.1
    max_clutter: float = 0.4

    def __post_init__(self) -> None:
        if not 0 <= self.max_outlier_ratio < 1:
            raise ValueError(f"max_outlier_ratio must be in [0, 1), got {self.max_outlier_ratio}")
        if not 0 <= self.clutter_probability <= 1:
            raise ValueError("clutter_probability must be in [0, 1]")
        if not 0 <= self.min_clutter <= self.max_clutter < 1:
            raise ValueError("need 0 <= min_clutter <= max_clutter < 1")
        if self.max_outlier_ratio + self.max_clutter >= 1:
            raise ValueError("max_outlier_ratio + max_clutter must stay below 1")

    def to_dict(self) -> dict:
        return asdict(self)


def _slots(b: int, m: int, counts: Tensor, generator: torch.Generator) -> Tensor:
    """(B, M) bool: ``counts[b]`` random slots of row b."""
    ranks = torch.rand(b, m, generator=generator).argsort(1).argsort(1)
    return ranks < counts[:, None]


def corrupt_source(pairs: Pairs, config: CorruptionConfig, generator: torch.Generator) -> Pairs:
    """``pairs`` with noise, outliers and clutter in their sources (same shapes).

    Args:
        pairs: a batch, template (B, N, 3), source (B, M, 3), in the source frame.
        config: the amounts.
        generator: seeded torch generator; the same seed gives the same corruption.

    Returns:
        Pairs whose ``source_mask`` (B, M) is False for outliers and clutter (and for
        points that were already False). Template, mask and transform are unchanged.
    """
    source, keep = pairs.source.clone(), pairs.source_mask.clone()
    b, m, _ = source.shape
    if config.max_noise > 0:
        sigma = torch.rand(b, 1, 1, generator=generator) * config.max_noise
        noise = torch.randn(source.shape, generator=generator) * sigma
        source = source + torch.maximum(torch.minimum(noise, 3 * sigma), -3 * sigma)
    box = source  # outliers fill the source's own box, grown by 5%, whatever clutter adds
    lo, hi = source.amin(1, keepdim=True), source.amax(1, keepdim=True)
    centre, radius = (lo + hi) / 2, ((hi - lo) / 2).norm(dim=-1, keepdim=True)
    free = torch.ones(b, m, dtype=torch.bool)

    if config.clutter_probability > 0 and b > 1 and config.max_clutter > 0:
        cluttered = torch.rand(b, generator=generator) < config.clutter_probability
        span = config.max_clutter - config.min_clutter
        fraction = config.min_clutter + torch.rand(b, generator=generator) * span
        counts = torch.where(cluttered, (fraction * m).round().long(), 0)
        slots = _slots(b, m, counts, generator)
        other = pairs.template.roll(1, dims=0)  # another object of the batch
        other_radius = centroid_radius(other).clamp_min(1e-9)[:, None, None]
        other = other - other.mean(1, keepdim=True)
        rot = random_rotation(b, 180.0, generator)
        scale = 0.5 + 0.5 * torch.rand(b, 1, 1, generator=generator)
        other = other @ rot.transpose(1, 2) / other_radius * radius * scale
        direction = torch.randn(b, 1, 3, generator=generator)
        direction = direction / direction.norm(dim=-1, keepdim=True).clamp_min(1e-9)
        distance = (1.2 + 0.8 * torch.rand(b, 1, 1, generator=generator)) * radius
        pick = torch.randint(0, other.shape[1], (b, m), generator=generator)
        clutter = torch.gather(other, 1, pick[..., None].expand(-1, -1, 3))
        clutter = clutter + centre + direction * distance
        source = torch.where(slots[..., None], clutter, source)
        keep &= ~slots
        free &= ~slots

    if config.max_outlier_ratio > 0:
        ratio = torch.rand(b, generator=generator) * config.max_outlier_ratio
        counts = (ratio * m).round().long()
        # Outliers take slots clutter left free.
        ranks = torch.where(free, torch.rand(b, m, generator=generator), 2.0).argsort(1).argsort(1)
        slots = ranks < counts[:, None]
        outliers = uniform_outliers(box, m, generator, grow=0.05)
        source = torch.where(slots[..., None], outliers, source)
        keep &= ~slots

    return type(pairs)(pairs.template, source, pairs.mask, pairs.transform, keep)

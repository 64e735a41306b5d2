"""Seeded, vectorised generation of (template, partial source) training and test pairs.

Two protocols:

``"paper"`` (default)
    A viewpoint uniform on a sphere of radius ``view_distance`` around the
    object; the source keeps the ``keep_ratio * N`` template points nearest to it
    (a simulated sensor view). Then a rotation about a uniform random axis by an
    angle uniform in [0, ``max_angle_deg``] and a translation uniform in
    [-``max_translation``, ``max_translation``]^3 move the source.

``"official"``
    The authors' code: a random twist of magnitude uniform in
    [0, ``official_max_twist``] through the SE(3) exponential moves the whole
    template; the source keeps the ``official_keep`` points nearest to a far
    point at +-500 * (1, 1, 1) (plus U[0,1)^3), chosen in the moved frame.

Either way the ground-truth ``transform`` maps source points into the template
frame (see :mod:`masknet.geometry.se3`), and ``mask[b, i]`` says whether template
point ``i`` is seen by the source.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import asdict, dataclass
from typing import Literal, NamedTuple

import numpy as np
import torch
from torch import Tensor

from masknet.geometry import (
    invert_transform,
    knn_points,
    make_transform,
    random_rotation,
    se3_exp,
    transform_points,
)

__all__ = [
    "PairConfig",
    "Pairs",
    "make_pairs",
    "iterate_pairs",
    "make_test_pairs",
    "sample_pair",
    "derive_seed",
]


@dataclass(frozen=True)
class PairConfig:
    """How a pair is made. Distances are in units of the (unit-radius) shapes."""

    keep_ratio: float = 0.7
    max_angle_deg: float = 45.0
    max_translation: float = 1.0
    noise_sigma: float = 0.0
    noise_clip: float = 0.05
    outlier_ratio: float = 0.0
    outlier_target: Literal["source", "template"] = "source"
    view_distance: float = 500.0
    protocol: Literal["paper", "official"] = "paper"
    official_keep: int = 768
    official_max_twist: float = 0.8

    def __post_init__(self) -> None:
        if not 0 < self.keep_ratio <= 1:
            raise ValueError(f"keep_ratio must be in (0, 1], got {self.keep_ratio}")
        if self.protocol not in ("paper", "official"):
            raise ValueError(f"protocol must be 'paper' or 'official', got {self.protocol!r}")
        if self.outlier_target not in ("source", "template"):
            raise ValueError(
                f"outlier_target must be 'source' or 'template', got {self.outlier_target!r}"
            )
        if not 0 <= self.outlier_ratio < 1:
            raise ValueError(f"outlier_ratio must be in [0, 1), got {self.outlier_ratio}")

    def to_dict(self) -> dict:
        return asdict(self)


class Pairs(NamedTuple):
    """A batch of pairs (all float32 / bool torch tensors on CPU).

    template: (B, N, 3) full template, plus outliers if ``outlier_target="template"``.
    source: (B, M, 3) partial, moved, optionally noisy source, plus outliers if
        ``outlier_target="source"``.
    mask: (B, N) bool, template points seen by the source (outliers are False).
    transform: (B, 4, 4) ground truth mapping source points into the template frame.
    source_mask: (B, M) bool, False for source points that are outliers.
    """

    template: Tensor
    source: Tensor
    mask: Tensor
    transform: Tensor
    source_mask: Tensor

    def rows(self, rows: slice) -> Pairs:
        """The pairs ``rows`` selects (a slice of the batch), every field alike."""
        return Pairs(*(field[rows] for field in self))


def derive_seed(*parts: int) -> int:
    """A 63-bit seed from integers (seed, epoch, batch, ...), stable across platforms."""
    # The length goes first: SeedSequence pads with zeros, so (1, 2) and (1, 2, 0) would collide.
    entropy = [len(parts), *parts]
    return int(np.random.SeedSequence(entropy).generate_state(1, np.uint64)[0] >> np.uint64(1))


def _random_subset(batch: int, n: int, k: int, generator: torch.Generator) -> Tensor:
    """(batch, k) random distinct indices in [0, n), one independent draw per row."""
    return torch.rand(batch, n, generator=generator).argsort(dim=1)[:, :k]


def _gather(points: Tensor, idx: Tensor) -> Tensor:
    return torch.gather(points, 1, idx[..., None].expand(-1, -1, points.shape[-1]))


def uniform_outliers(
    cloud: Tensor, count: int, generator: torch.Generator, grow: float = 0.0
) -> Tensor:
    """(B, count, 3) points uniform in each cloud's (B, P, 3) axis-aligned bounding box,
    grown by ``grow`` of its size on every side."""
    lo, hi = cloud.amin(1, keepdim=True), cloud.amax(1, keepdim=True)
    margin = (hi - lo) * grow
    u = torch.rand(cloud.shape[0], count, 3, generator=generator)
    return lo - margin + u * (hi - lo + 2 * margin)


def make_pairs(
    clouds: Tensor | np.ndarray, config: PairConfig, generator: torch.Generator
) -> Pairs:
    """Make one pair per cloud.

    Args:
        clouds: (B, N, 3) full shapes, used as templates.
        config: the protocol and its ranges.
        generator: seeded torch generator; the same seed gives the same pairs.
    """
    template = torch.as_tensor(clouds, dtype=torch.float32)
    if template.dim() != 3 or template.shape[-1] != 3:
        raise ValueError(f"clouds must be (B, N, 3), got {tuple(template.shape)}")
    b, n, _ = template.shape

    if config.protocol == "paper":
        keep = max(3, round(config.keep_ratio * n))
        direction = torch.randn(b, 1, 3, generator=generator)
        view = direction / direction.norm(dim=-1, keepdim=True) * config.view_distance
        idx = knn_points(view, template, keep).idx[:, 0]
        rot = random_rotation(b, config.max_angle_deg, generator)
        trans = (torch.rand(b, 3, generator=generator) * 2 - 1) * config.max_translation
        moving = make_transform(rot, trans)  # template frame -> source frame
        moved = transform_points(moving, template)
    else:
        keep = config.official_keep
        if keep > n:
            raise ValueError(f"official protocol keeps {keep} points but clouds have {n}")
        xi = torch.randn(b, 6, generator=generator, dtype=torch.float64)
        magnitude = (
            torch.rand(b, 1, generator=generator, dtype=torch.float64) * config.official_max_twist
        )
        moving = se3_exp(xi / xi.norm(dim=-1, keepdim=True) * magnitude).float()
        moved = transform_points(moving, template)
        sign = torch.where(torch.rand(b, 1, 1, generator=generator) < 0.5, -1.0, 1.0)
        far = torch.rand(b, 1, 3, generator=generator) + 500.0 * sign
        idx = knn_points(far, moved, keep).idx[:, 0]

    mask = torch.zeros(b, n, dtype=torch.bool)
    mask.scatter_(1, idx, True)
    # Shuffle so that source order says nothing about which template point it came from.
    order = torch.rand(b, keep, generator=generator).argsort(dim=1)
    source = _gather(moved, torch.gather(idx, 1, order))

    if config.noise_sigma > 0:
        noise = torch.randn(source.shape, generator=generator) * config.noise_sigma
        source = source + noise.clamp(-config.noise_clip, config.noise_clip)

    source_mask = torch.ones(b, source.shape[1], dtype=torch.bool)
    if config.outlier_ratio > 0:
        target = source if config.outlier_target == "source" else template
        count = max(1, round(config.outlier_ratio * target.shape[1]))
        extra = uniform_outliers(target, count, generator)
        no = torch.zeros(b, count, dtype=torch.bool)
        if config.outlier_target == "source":
            source = torch.cat([source, extra], 1)
            source_mask = torch.cat([source_mask, no], 1)
        else:
            template = torch.cat([template, extra], 1)
            mask = torch.cat([mask, no], 1)

    return Pairs(template, source, mask, invert_transform(moving.double()).float(), source_mask)


def iterate_pairs(
    points: np.ndarray,
    config: PairConfig,
    batch_size: int,
    seed: int,
    epoch: int = 0,
    num_points: int | None = None,
    shuffle: bool = True,
    drop_last: bool = False,
) -> Iterator[Pairs]:
    """Batches of fresh pairs over a set of shapes, deterministic in (seed, epoch).

    Args:
        points: (S, N, 3) shapes.
        num_points: if smaller than N, each template is a random subset of that
            many points (drawn anew each epoch).
    """
    s, n, _ = points.shape
    order_gen = torch.Generator().manual_seed(derive_seed(seed, epoch, 0))
    order = torch.randperm(s, generator=order_gen) if shuffle else torch.arange(s)
    stop = s - s % batch_size if drop_last else s
    for i, start in enumerate(range(0, stop, batch_size)):
        gen = torch.Generator().manual_seed(derive_seed(seed, epoch, i + 1))
        clouds = torch.from_numpy(points[order[start : start + batch_size].numpy()])
        if num_points is not None and num_points < n:
            clouds = _gather(clouds, _random_subset(clouds.shape[0], n, num_points, gen))
        yield make_pairs(clouds, config, gen)


def make_test_pairs(
    points: np.ndarray, num_pairs: int, config: PairConfig, seed: int, batch_size: int = 256
) -> Pairs:
    """A fixed, seeded test set of ``num_pairs`` pairs.

    Shapes are drawn without replacement while they last (then cycled), so 1,000
    pairs from the 2,468 ModelNet40 test shapes use 1,000 distinct shapes.
    """
    s = points.shape[0]
    gen = torch.Generator().manual_seed(derive_seed(seed, 0))
    picks = torch.cat([torch.randperm(s, generator=gen) for _ in range(-(-num_pairs // s))])[
        :num_pairs
    ]
    batches = []
    for i, start in enumerate(range(0, num_pairs, batch_size)):
        gen_b = torch.Generator().manual_seed(derive_seed(seed, i + 1))
        batches.append(
            make_pairs(
                torch.from_numpy(points[picks[start : start + batch_size].numpy()]), config, gen_b
            )
        )
    return Pairs(*(torch.cat(parts) for parts in zip(*batches, strict=True)))


def sample_pair(
    seed: int = 3, config: PairConfig | None = None, shape: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One seeded pair from the bundled ModelNet40 sample, as numpy float64, to try things
    on: template (N, 3), source (M, 3) a partial, moved view of it (``config``, default
    the paper's protocol), and truth (4, 4), the transform that maps the source onto the
    template (``template ≈ source @ R.T + t``). ``shape`` indexes the sample's test shapes.

    It is :func:`make_test_pairs` on one shape; the default pair (seed 3, the first shape)
    is turned by 27.4 degrees and moved by 0.82.
    """
    from masknet.data.modelnet import bundled_sample_path, load_modelnet40

    shapes = load_modelnet40(bundled_sample_path(), "test").points[shape : shape + 1]
    pair = make_test_pairs(shapes, 1, config or PairConfig(), seed=seed)
    return tuple(a[0].double().numpy() for a in (pair.template, pair.source, pair.transform))

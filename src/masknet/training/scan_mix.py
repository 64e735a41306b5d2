"""Where a mask task's batches come from when real scans join ModelNet40 (:class:`ScanMix`),
and the batch plumbing every composed task shares.

Each epoch of a :class:`ScanMix` mixes three kinds of batch, shuffled together:

* the paper's ModelNet40 pairs (:mod:`masknet.data.pairs`), on a random
  ``modelnet_fraction`` of the training shapes, so the paper's figure is kept;
* sensor-like ModelNet40 pairs (:mod:`masknet.data.views`: visibility cut, independent
  sampling, noise, density fall-off) on ``modelnet_view_fraction`` of those batches;
* ``scan_batches`` batches cut from crops of real scans (:mod:`masknet.data.scans`).

Validation holds out whole scans (a fixed list of names) and ModelNet40 training shapes:
``val_modelnet_precision`` and ``val_scans_precision`` are logged apart, and
``val_precision``, their mean over equally many pairs, picks the best weights.

A task holds a ``ScanMix`` (composition, not a base class): :class:`~masknet.training.
masknet_task.MaskNetTask`, the two-sided and the refinement tasks take one, and
:class:`BatchChange` steps (corrupt the source, move it off the truth) apply after it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import torch

from masknet.data.pairs import PairConfig, Pairs, derive_seed, iterate_pairs
from masknet.data.scans import Scan, ScanCropConfig, iterate_scan_pairs, make_scan_test_pairs
from masknet.data.views import ViewConfig, make_view_pairs, normalize_cloud

__all__ = [
    "BatchChange",
    "MappedEpoch",
    "ScanMix",
    "ScanPairs",
    "ViewPairs",
    "by_kind",
]


class ScanPairs(Pairs):
    """Pairs cut from real scans (same fields as :class:`Pairs`)."""


class ViewPairs(Pairs):
    """Sensor-like pairs of ModelNet40 shapes (same fields as :class:`Pairs`)."""


KIND_OF = {ScanPairs: "scans", ViewPairs: "views", Pairs: "modelnet"}


def by_kind(batch: Pairs, metrics: dict[str, float]) -> dict[str, float]:
    """``metrics``, and each again under the name of the batch's kind (``scans_f1``,
    ``views_f1``, ``modelnet_f1``), so the log keeps the kinds apart."""
    kind = KIND_OF[type(batch)]
    return metrics | {f"{kind}_{k}": v for k, v in metrics.items()}


class _Epoch:
    """One epoch's batches: an iterable with a length (for the progress bar)."""

    def __init__(self, kinds: list[str], makers: dict[str, Iterator[Pairs]]) -> None:
        self.kinds, self.makers = kinds, makers

    def __len__(self) -> int:
        return len(self.kinds)

    def __iter__(self) -> Iterator[Pairs]:
        for kind in self.kinds:
            yield next(self.makers[kind])


class MappedEpoch:
    """An epoch's batches, each passed through ``change(batch, generator)`` with its own
    seeded generator (seed, epoch, ``tag``, batch index); keeps the length and the batch
    kinds (:class:`ScanPairs`, :class:`ViewPairs`)."""

    def __init__(
        self,
        batches,
        change: Callable[[Pairs, torch.Generator], Pairs],
        seed: int,
        epoch: int,
        tag: int,
    ) -> None:
        self.batches, self.change = batches, change
        self.seed, self.epoch, self.tag = seed, epoch, tag

    def __len__(self) -> int:
        return len(self.batches)

    def __iter__(self) -> Iterator[Pairs]:
        for i, batch in enumerate(self.batches):
            gen = torch.Generator().manual_seed(derive_seed(self.seed, self.epoch, self.tag, i))
            yield type(batch)(*self.change(batch, gen))


class BatchChange(NamedTuple):
    """A step applied to every batch after it is made: ``change(batch, generator)`` with a
    generator seeded by (seed, epoch, ``tag``, batch index); validation seeds it with
    ``seed + val_offset``."""

    change: Callable[[Pairs, torch.Generator], Pairs]
    tag: int
    val_offset: int


def changed_train(batches, changes: tuple[BatchChange, ...], seed: int, epoch: int):
    """An epoch's batches through each of ``changes`` in order."""
    for step in changes:
        batches = MappedEpoch(batches, step.change, seed, epoch, step.tag)
    return batches


def changed_val(batches: list[Pairs], changes: tuple[BatchChange, ...], seed: int) -> list[Pairs]:
    """Validation batches through each of ``changes`` in order (fixed generators)."""
    for step in changes:
        batches = list(MappedEpoch(batches, step.change, seed + step.val_offset, 0xBA1, step.tag))
    return batches


@dataclass
class ScanMix:
    """ModelNet40 pairs mixed with sensor-like views and pairs cut from real scans.

    scans, val_scans: training and validation scans (whole scans, held apart); none, with
        ``scan_batches`` 0, mixes ModelNet40 pairs and views only.
    view: how sensor-like pairs are cut (by default with noise up to 1% of the radius).
    crop: how crops are cut from the scans.
    scan_batches: scan batches per epoch.
    modelnet_fraction: fraction of the ModelNet40 training shapes used per epoch.
    modelnet_view_fraction: fraction of those ModelNet40 batches cut as sensor-like views.
    modelnet_view_points: template points of a ModelNet40 view pair.
    """

    scans: list[Scan] = field(default_factory=list)
    val_scans: list[Scan] = field(default_factory=list)
    view: ViewConfig = field(
        default_factory=lambda: ViewConfig(noise_sigma=0.01, random_noise=True)
    )
    crop: ScanCropConfig = field(default_factory=ScanCropConfig)
    scan_batches: int = 128
    modelnet_fraction: float = 0.5
    modelnet_view_fraction: float = 0.25
    modelnet_view_points: int = 384

    def __post_init__(self) -> None:
        if not self.scans and self.scan_batches:
            raise ValueError("scan batches need at least one training scan")
        if not 0 <= self.modelnet_fraction <= 1 or not 0 <= self.modelnet_view_fraction <= 1:
            raise ValueError("modelnet_fraction and modelnet_view_fraction must be in [0, 1]")

    def _modelnet_batches(
        self,
        pairs: PairConfig,
        num_points: int,
        points: np.ndarray,
        batch_size: int,
        seed: int,
        epoch: int,
    ) -> Iterator[Pairs]:
        rng = np.random.default_rng(derive_seed(seed, epoch, 0x3D))
        for batch in iterate_pairs(
            points, pairs, batch_size, seed, epoch, num_points, drop_last=True
        ):
            if rng.random() < self.modelnet_view_fraction:
                # The same shapes, cut as sensor-like views (the paper's template is the
                # whole shape, so its points are the cloud).
                view = dataclasses.replace(self.view, template_points=self.modelnet_view_points)
                clouds = [normalize_cloud(c) for c in batch.template.numpy()]
                yield ViewPairs(*make_view_pairs(clouds, view, rng))
            else:
                yield batch

    def train_batches(
        self,
        pairs: PairConfig,
        num_points: int,
        points: np.ndarray,
        batch_size: int,
        seed: int,
        epoch: int,
    ):
        """One epoch: ModelNet40 batches of ``pairs`` (``num_points`` template points) on
        a random share of ``points``, views among them, and scan batches, shuffled."""
        rng = np.random.default_rng(derive_seed(seed, epoch, 0xE9))
        count = round(self.modelnet_fraction * len(points))
        subset = points[np.sort(rng.permutation(len(points))[:count])]
        n_modelnet = len(subset) // batch_size
        kinds = ["modelnet"] * n_modelnet + ["scans"] * self.scan_batches
        rng.shuffle(kinds)
        makers = {
            "modelnet": self._modelnet_batches(pairs, num_points, subset, batch_size, seed, epoch),
            "scans": (
                ScanPairs(*batch)
                for batch in iterate_scan_pairs(
                    self.scans, self.view, self.crop, self.scan_batches, batch_size, seed, epoch
                )
            ),
        }
        return _Epoch(kinds, makers)

    def val_batches(
        self, batches: list[Pairs], num_pairs: int, batch_size: int, seed: int
    ) -> list[Pairs]:
        """The ModelNet40 validation ``batches`` and pairs of the held-out scans."""
        if self.val_scans:
            per_scan = -(-num_pairs // len(self.val_scans))
            view = dataclasses.replace(self.view, noise_sigma=0.002, random_noise=False)
            pairs, _ = make_scan_test_pairs(self.val_scans, per_scan, view, self.crop, seed + 7919)
            batches = batches + [
                ScanPairs(*(x[i : i + batch_size] for x in pairs))
                for i in range(0, len(pairs.template), batch_size)
            ]
        return batches

    def describe(self) -> dict:
        return {
            "scans": [s.name for s in self.scans],
            "val_scans": [s.name for s in self.val_scans],
            "view": self.view.to_dict(),
            "crop": dataclasses.asdict(self.crop),
            "scan_batches": self.scan_batches,
            "modelnet_fraction": self.modelnet_fraction,
            "modelnet_view_fraction": self.modelnet_view_fraction,
            "modelnet_view_points": self.modelnet_view_points,
        }

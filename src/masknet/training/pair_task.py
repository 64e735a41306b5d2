"""What every pair-based training task shares: fresh seeded pairs per epoch, a fixed
validation set at the stored resolution, and the composed parts of a task's batches: real
scans mixed in (:class:`~masknet.training.scan_mix.ScanMix`) and steps applied to every
batch (:class:`~masknet.training.scan_mix.BatchChange`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from torch import nn

from masknet.data.pairs import PairConfig, Pairs, iterate_pairs, make_test_pairs
from masknet.training.scan_mix import BatchChange, ScanMix, changed_train, changed_val

__all__ = ["PairTask"]


@dataclass
class PairTask:
    """Base of the tasks in :mod:`masknet.training` (see :class:`masknet.training.loop.Task`).

    pairs: how training and validation pairs are made.
    num_points: template points per training pair (a fresh random subset of each
        shape every epoch when smaller than the stored resolution).
    mix: real scans and sensor-like views mixed into the ModelNet40 pairs, or None.
    """

    pairs: PairConfig = field(default_factory=PairConfig)
    num_points: int = 1024
    mix: ScanMix | None = field(default=None, kw_only=True)

    def batch_changes(self) -> tuple[BatchChange, ...]:
        """Steps applied to every batch, in order (none here; the two-sided task corrupts
        the source, the refinement task also moves it off the truth)."""
        return ()

    def train_batches(self, points: np.ndarray, batch_size: int, seed: int, epoch: int):
        if self.mix is None:
            batches = iterate_pairs(
                points, self.pairs, batch_size, seed, epoch, self.num_points, drop_last=True
            )
        else:
            batches = self.mix.train_batches(
                self.pairs, self.num_points, points, batch_size, seed, epoch
            )
        return changed_train(batches, self.batch_changes(), seed, epoch)

    def val_batches(
        self, points: np.ndarray, num_pairs: int, batch_size: int, seed: int
    ) -> list[Pairs]:
        batches = []
        if len(points):
            # Validation always uses the full stored resolution, like the test set.
            pairs = make_test_pairs(points, num_pairs, self.pairs, seed=seed + 7919)
            batches = [
                pairs.rows(slice(i, i + batch_size))
                for i in range(0, len(pairs.template), batch_size)
            ]
        if self.mix is not None:
            batches = self.mix.val_batches(batches, num_pairs, batch_size, seed)
        return changed_val(batches, self.batch_changes(), seed)

    def export(self, model: nn.Module, path: Path, metadata: dict) -> None:
        model.save(path, metadata)

    def describe(self) -> dict:
        """The settings that define the run (compared on --resume): shared ones, the scan
        mix's, plus the task's :meth:`describe_extra`."""
        return (
            {
                "model": dict(getattr(self, "model_config", {})),
                "name": getattr(self, "name", ""),
                "pairs": self.pairs.to_dict(),
                "num_points": self.num_points,
            }
            | ({} if self.mix is None else self.mix.describe())
            | self.describe_extra()
        )

    def describe_extra(self) -> dict:
        return {}

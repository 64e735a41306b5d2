"""What every pair-based training task shares: fresh seeded pairs per epoch and a
fixed validation set at the stored resolution."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from torch import nn

from masknet.data.pairs import PairConfig, Pairs, iterate_pairs, make_test_pairs

__all__ = ["PairTask"]


@dataclass
class PairTask:
    """Base of the tasks in :mod:`masknet.training` (see :class:`masknet.training.loop.Task`).

    pairs: how training and validation pairs are made.
    num_points: template points per training pair (a fresh random subset of each
        shape every epoch when smaller than the stored resolution).
    """

    pairs: PairConfig = field(default_factory=PairConfig)
    num_points: int = 1024

    def train_batches(self, points: np.ndarray, batch_size: int, seed: int, epoch: int):
        return iterate_pairs(
            points, self.pairs, batch_size, seed, epoch, self.num_points, drop_last=True
        )

    def val_batches(
        self, points: np.ndarray, num_pairs: int, batch_size: int, seed: int
    ) -> list[Pairs]:
        if not len(points):
            return []
        # Validation always uses the full stored resolution, like the test set.
        pairs = make_test_pairs(points, num_pairs, self.pairs, seed=seed + 7919)
        return [
            Pairs(*(x[i : i + batch_size] for x in pairs))
            for i in range(0, len(pairs.template), batch_size)
        ]

    def export(self, model: nn.Module, path: Path, metadata: dict) -> None:
        model.save(path, metadata)

    def describe(self) -> dict:
        """The settings that define the run (compared on --resume): shared ones plus
        the subclass's :meth:`describe_extra`."""
        return {
            "model": dict(getattr(self, "model_config", {})),
            "name": getattr(self, "name", ""),
            "pairs": self.pairs.to_dict(),
            "num_points": self.num_points,
        } | self.describe_extra()

    def describe_extra(self) -> dict:
        return {}

"""masknet.training.pair_task: seeded pairs, a fixed validation set, the scan mix and the
per-batch steps composed in order."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.data.pairs import PairConfig, Pairs
from masknet.training.pair_task import PairTask
from masknet.training.scan_mix import BatchChange, ScanMix


@pytest.fixture(scope="module")
def shapes() -> np.ndarray:
    return load_modelnet40(bundled_sample_path(), "test").points[:32]


def _shift(amount: float):
    def change(batch: Pairs, generator: torch.Generator) -> Pairs:
        return batch._replace(source=batch.source + amount)

    return change


class Shifted(PairTask):
    """A task whose batches' sources are moved by 1, then by 10."""

    def batch_changes(self):
        return (BatchChange(_shift(1.0), 1, 0), BatchChange(_shift(10.0), 2, 0))


def test_batches_are_seeded_fresh_per_epoch_and_validation_is_fixed(shapes):
    task = PairTask(pairs=PairConfig(), num_points=512)
    first = next(iter(task.train_batches(shapes, 8, seed=0, epoch=0)))
    again = next(iter(task.train_batches(shapes, 8, seed=0, epoch=0)))
    later = next(iter(task.train_batches(shapes, 8, seed=0, epoch=1)))
    torch.testing.assert_close(first.source, again.source)
    assert first.template.shape[1] == 512 and not torch.equal(first.template, later.template)
    val = task.val_batches(shapes, 10, 4, seed=0)
    assert [len(b.template) for b in val] == [4, 4, 2] and val[0].template.shape[1] == 1024


def test_the_steps_apply_to_every_batch_in_order(shapes):
    plain, shifted = PairTask(num_points=256), Shifted(num_points=256)
    a = next(iter(plain.train_batches(shapes, 8, 0, 0)))
    b = next(iter(shifted.train_batches(shapes, 8, 0, 0)))
    torch.testing.assert_close(b.source, a.source + 11.0)
    va, vb = plain.val_batches(shapes, 4, 4, 0)[0], shifted.val_batches(shapes, 4, 4, 0)[0]
    torch.testing.assert_close(vb.source, va.source + 11.0)


def test_describe_names_the_mix_only_where_there_is_one():
    assert "scans" not in PairTask().describe()
    mixed = PairTask(mix=ScanMix(scan_batches=0)).describe()
    assert mixed["scans"] == [] and mixed["modelnet_fraction"] == 0.5
    with pytest.raises(ValueError, match="training scan"):
        ScanMix()  # scan batches without scans

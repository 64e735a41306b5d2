"""masknet.training.two_sided_task: the sources corrupted, the source mask learned."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.training.two_sided_task import TwoSidedTask, outliers_removed


@pytest.fixture(scope="module")
def shapes() -> np.ndarray:
    return load_modelnet40(bundled_sample_path(), "test").points[:16]


def test_every_batch_has_corrupted_sources_seeded_per_batch(shapes):
    task = TwoSidedTask(init="")  # 1,024 points: enough for the sensor-like views among them
    batches = list(task.train_batches(shapes, 4, seed=0, epoch=0))
    again = list(task.train_batches(shapes, 4, seed=0, epoch=0))
    assert batches and all((~b.source_mask).any() for b in batches)  # outliers or clutter
    for a, b in zip(batches, again, strict=True):
        torch.testing.assert_close(a.source, b.source)
    described = task.describe()
    assert described["init"] == "" and "corruption" in described and described["scans"] == []


def test_outliers_removed_counts_the_rejected_corrupted_points():
    truth = torch.tensor([[True, True, False, False]])
    assert outliers_removed(torch.tensor([[True, True, False, True]]), truth) == 0.5
    assert outliers_removed(torch.tensor([[True, True, True, True]]), truth) == 0.0
    assert (
        outliers_removed(torch.ones(1, 4, dtype=torch.bool), torch.ones(1, 4, dtype=torch.bool))
        == 0
    )

"""MaskNet trained on ModelNet40 mixed with real-scan crops: kinds logged apart, resumable."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from scipy.spatial import cKDTree

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.data.pairs import PairConfig
from masknet.data.scans import Scan, ScanCropConfig
from masknet.data.views import ViewConfig
from masknet.errors import MaskNetError
from masknet.training import TrainConfig, fit
from masknet.training.scan_task import ScanMaskNetTask, ScanPairs, ViewPairs

TINY = {"encoder_channels": (16, 16, 32), "head_channels": (32, 16)}


def _scan(name: str, seed: int) -> Scan:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-2, 2, (2000, 2))
    points = np.column_stack([xy, 0.3 * np.sin(2 * xy[:, 0])]).astype(np.float32)
    return Scan(name, points, cKDTree(points))


def _task(**changes) -> ScanMaskNetTask:
    settings = dict(
        pairs=PairConfig(),
        num_points=128,
        model_config=TINY,
        loss="bce",
        scans=[_scan("a", 0), _scan("b", 1)],
        val_scans=[_scan("c", 2)],
        view=ViewConfig(template_points=64, noise_sigma=0.01, random_noise=True),
        crop=ScanCropConfig(crop_points=(256, 512)),
        scan_batches=3,
        modelnet_fraction=1.0,
        modelnet_view_fraction=0.5,
        modelnet_view_points=48,
    )
    return ScanMaskNetTask(**(settings | changes))


@pytest.fixture(scope="module")
def shapes() -> np.ndarray:
    return load_modelnet40(bundled_sample_path(), "test").points[:, :128]


def test_an_epoch_mixes_every_kind_in_a_seeded_order(shapes):
    task = _task()
    epoch = task.train_batches(shapes, 16, seed=0, epoch=0)
    kinds = [type(batch) for batch in epoch]
    assert len(kinds) == len(epoch) == len(shapes) // 16 + 3
    assert kinds.count(ScanPairs) == 3 and ViewPairs in kinds
    again = [type(batch) for batch in task.train_batches(shapes, 16, seed=0, epoch=0)]
    assert again == kinds


def test_fit_logs_scan_and_modelnet_validation_apart_and_resumes(tmp_path, shapes):
    config = TrainConfig(
        out_dir=str(tmp_path),
        epochs=1,
        batch_size=16,
        lr=3e-3,
        precision="fp32",
        val_fraction=0.2,
        val_pairs=32,
        threads=1,
    )
    history = fit(_task(), shapes, config)
    row = history[0]
    for key in ("val_precision", "val_modelnet_precision", "val_scans_precision"):
        assert 0 < row[key] <= 1
    mean = (row["val_modelnet_precision"] + row["val_scans_precision"]) / 2
    assert row["val_precision"] == pytest.approx(mean, abs=0.05)
    config.epochs = 2
    history = fit(_task(), shapes, config, resume=True)
    assert [r["epoch"] for r in history] == [1, 2]
    header = next(csv.reader(open(tmp_path / "log.csv")))
    assert "train_scans_precision" in header and "val_scans_precision" in header
    # A changed scan list is a different run: resuming it is refused.
    config.epochs = 3
    with pytest.raises(MaskNetError, match="task/pair settings"):
        fit(_task(scans=[_scan("a", 0)]), shapes, config, resume=True)


def test_scans_alone_train_and_validate_without_modelnet(tmp_path):
    config = TrainConfig(
        out_dir=str(tmp_path), epochs=1, batch_size=16, precision="fp32", val_pairs=16, threads=1
    )
    history = fit(_task(modelnet_fraction=0.0), np.zeros((0, 128, 3), np.float32), config)
    assert "val_scans_precision" in history[0] and "val_modelnet_precision" not in history[0]
    assert "train_modelnet_precision" not in history[0]


def test_a_task_needs_scans():
    with pytest.raises(ValueError, match="at least one training scan"):
        _task(scans=[])

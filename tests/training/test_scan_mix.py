"""masknet.training.scan_mix: MaskNet trained on ModelNet40 mixed with real-scan crops (a
MaskNetTask holding a ScanMix): kinds logged apart, resumable."""

from __future__ import annotations

import csv
import dataclasses

import numpy as np
import pytest
import torch

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.data.pairs import PairConfig
from masknet.data.scans import Scan, ScanCropConfig, make_scan_test_pairs
from masknet.data.views import ViewConfig
from masknet.errors import MaskNetError
from masknet.models import MaskNet
from masknet.training import MaskNetTask, TrainConfig, fit
from masknet.training.scan_mix import ScanMix, ScanPairs, ViewPairs

TINY = {"encoder_channels": (16, 16, 32), "head_channels": (32, 16)}


def _scan(name: str, seed: int) -> Scan:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-2, 2, (2000, 2))
    points = np.column_stack([xy, 0.3 * np.sin(2 * xy[:, 0])]).astype(np.float32)
    return Scan(name, points)


MIX_FIELDS = {f.name for f in dataclasses.fields(ScanMix)}


def _task(**changes) -> MaskNetTask:
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
    settings |= changes
    mix = ScanMix(**{k: v for k, v in settings.items() if k in MIX_FIELDS})
    return MaskNetTask.on_scans(mix, **{k: v for k, v in settings.items() if k not in MIX_FIELDS})


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
    # 32 validation pairs of each kind, two batches each: the overall figure is their mean.
    mean = (row["val_modelnet_precision"] + row["val_scans_precision"]) / 2
    assert row["val_precision"] == pytest.approx(mean, abs=1e-6)
    assert row["val_modelnet_precision"] != pytest.approx(row["val_scans_precision"], abs=1e-3), row
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
    task = _task(modelnet_fraction=0.0)
    history = fit(task, np.zeros((0, 128, 3), np.float32), config)
    assert "val_modelnet_precision" not in history[0]
    assert "train_modelnet_precision" not in history[0]
    # The logged figure, computed here: the saved weights' top-k precision on 16 seeded
    # pairs from the held-out scan (the validation's view: fixed noise of 0.2%).
    view = dataclasses.replace(task.mix.view, noise_sigma=0.002, random_noise=False)
    seed = config.seed + 7919  # the task offsets the validation seed by 7919
    pairs, _ = make_scan_test_pairs(task.mix.val_scans, 16, view, task.mix.crop, seed)
    model = MaskNet.from_file(tmp_path / "last.safetensors").eval()
    with torch.no_grad():
        scores = model(pairs.template, pairs.source)
    k = pairs.source.shape[1]
    top = scores.argsort(dim=1, descending=True)[:, :k]
    precision = pairs.mask.gather(1, top).float().mean()
    assert history[0]["val_scans_precision"] == pytest.approx(float(precision), abs=1e-5)


def test_a_task_needs_scans():
    with pytest.raises(ValueError, match="at least one training scan"):
        _task(scans=[])

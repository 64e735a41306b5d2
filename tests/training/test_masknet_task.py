"""masknet.training.masknet_task: MaskNet's loss and metrics, the denoising role, on scans."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.data.pairs import PairConfig
from masknet.training import MaskNetTask
from masknet.training.scan_mix import ScanMix

TINY = {"encoder_channels": (16, 16, 32), "head_channels": (32, 16)}


@pytest.fixture(scope="module")
def batch():
    shapes = load_modelnet40(bundled_sample_path(), "test").points[:8]
    task = MaskNetTask(model_config=TINY, num_points=256)
    return next(iter(task.train_batches(shapes, 8, 0, 0)))


@pytest.mark.parametrize("loss", ["mse", "bce"])
def test_a_step_gives_a_loss_with_a_gradient_and_the_precision(batch, loss):
    task = MaskNetTask(model_config=TINY, loss=loss)
    torch.manual_seed(0)
    model = task.build_model()
    value, metrics = task.step(model, batch, torch.device("cpu"))
    value.backward()
    assert value.item() > 0 and next(model.parameters()).grad is not None
    assert set(metrics) == {"precision", "recall"} and 0 <= metrics["precision"] <= 1


def test_the_denoising_role_scores_the_source_and_reports_f1():
    task = MaskNetTask.denoising(PairConfig(outlier_ratio=0.1), model_config=TINY)
    assert task.role == "denoise" and task.metric == "f1"
    assert task.model_config["centring"] == "source"
    assert task.describe()["role"] == "denoise"


def test_on_scans_names_the_run_and_logs_metrics_by_kind(batch):
    task = MaskNetTask.on_scans(ScanMix(scan_batches=0), model_config=TINY)
    assert task.name == "masknet-scans" and task.describe()["scan_batches"] == 0
    _, metrics = task.step(task.build_model(), batch, torch.device("cpu"))
    assert "modelnet_precision" in metrics and np.isclose(
        metrics["modelnet_precision"], metrics["precision"]
    )

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


def test_a_teacher_blends_its_scores_into_the_target(batch, tmp_path):
    """Distilling: the BCE target is w * teacher's score + (1 - w) * label; a student
    equal to its teacher at w = 1 sits at the minimum (zero gradient)."""
    torch.manual_seed(0)
    teacher = MaskNetTask(model_config=TINY).build_model().eval()
    path = tmp_path / "teacher.safetensors"
    teacher.save(path)
    task = MaskNetTask(model_config=TINY, loss="bce", teacher=str(path), distill_weight=1.0)
    assert task.describe()["teacher"] == str(path)
    target = batch.mask.float()
    soft = task._soft_target(batch.template, batch.source, target)
    with torch.no_grad():
        expected = torch.sigmoid(teacher(batch.template, batch.source, logits=True))
    torch.testing.assert_close(soft, expected)
    half = MaskNetTask(model_config=TINY, loss="bce", teacher=str(path), distill_weight=0.5)
    torch.testing.assert_close(
        half._soft_target(batch.template, batch.source, target), 0.5 * expected + 0.5 * target
    )
    student = MaskNetTask(model_config=TINY).build_model().eval()
    student.load_state_dict(teacher.state_dict())
    loss, _ = task.step(student, batch, torch.device("cpu"))
    loss.backward()
    grad = torch.cat([p.grad.flatten() for p in student.parameters() if p.grad is not None])
    assert grad.abs().max() < 1e-5


@pytest.mark.parametrize(
    ("settings", "message"),
    [({"loss": "mse"}, "loss='bce'"), ({"loss": "bce", "distill_weight": 1.5}, r"\[0, 1\]")],
)
def test_distilling_refuses_mse_and_weights_outside_0_1(settings, message):
    with pytest.raises(ValueError, match=message):
        MaskNetTask(model_config=TINY, teacher="modelnet40", **settings)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--model", "dcp", "--distill", "modelnet40"], "--distill trains a MaskNet"),
        (["--distill", "modelnet40", "--loss", "mse"], "loss='bce'"),
    ],
)
def test_the_cli_refuses_distilling_what_it_cannot(extra, message, tmp_path, capsys):
    from masknet.cli import main

    code = main(["train", "--output", str(tmp_path / "r"), *extra])
    assert code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "r").exists()

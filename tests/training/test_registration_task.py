"""The registration networks' task: the papers' training, and Mask-X training on the template
points a frozen MaskNet keeps."""

import numpy as np
import pytest
import torch

from masknet.cli import main
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.training import RegistrationTask


@pytest.fixture(scope="module")
def batch():
    shapes = load_modelnet40(bundled_sample_path()).points
    return make_test_pairs(shapes, 4, PairConfig(), seed=0)


def small_task(**kwargs) -> RegistrationTask:
    config = {"encoder_channels": [8, 16]}
    return RegistrationTask(name="pointnetlk", iterations=2, model_config=config, **kwargs)


def test_masked_training_gives_the_network_the_points_masknet_keeps(batch):
    task = small_task(template_mask="modelnet40")
    kept = task._masked_template(batch)
    m = batch.source.shape[1]
    assert kept.shape == (4, m, 3)  # top-k with k = M
    for b in range(4):  # rows of the template, each once
        rows = {tuple(p) for p in batch.template[b].numpy().round(6)}
        assert {tuple(p) for p in kept[b].numpy().round(6)} <= rows
        assert len({tuple(p) for p in kept[b].numpy().round(6)}) == m
    # Mostly the points the source sees: MaskNet's precision on these pairs.
    truth = batch.template[batch.mask].reshape(4, -1, 3)
    seen = [
        np.isin(
            kept[b].numpy().round(6).view("f4,f4,f4"), truth[b].numpy().round(6).view("f4,f4,f4")
        ).mean()
        for b in range(4)
    ]
    assert np.mean(seen) > 0.8


def test_masked_training_steps_and_says_so(batch):
    task = small_task(template_mask="modelnet40")
    model = task.build_model()
    loss, metrics = task.step(model, batch, torch.device("cpu"))
    loss.backward()
    assert torch.isfinite(loss) and metrics["rotation_error_deg"] >= 0
    assert task.describe()["template_mask"] == "modelnet40"
    assert "template_mask" not in small_task().describe()  # the papers' training


def test_the_command_refuses_a_template_mask_for_a_mask_network(tmp_path, capsys):
    code = main(
        [
            "train",
            "--model",
            "masknet",
            "--template-mask",
            "modelnet40",
            "--output",
            str(tmp_path / "r"),
        ]
    )
    assert code == 2
    assert "--template-mask trains a registration network" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_the_command_refuses_an_unknown_mask_network_before_loading_data(tmp_path, capsys):
    code = main(
        [
            "train",
            "--model",
            "pointnetlk",
            "--template-mask",
            "nonesuch",
            "--output",
            str(tmp_path / "r"),
        ]
    )
    assert code == 2
    assert "nonesuch" in capsys.readouterr().err

"""``masknet train``'s messages: the learning rate printed exactly, and an interrupt that
says how to continue."""

from __future__ import annotations

import numpy as np
import pytest

import masknet.training
from masknet.cli import main
from masknet.data import bundled_sample_path


@pytest.fixture
def tiny_data(tmp_path):
    """A ModelNet40-style .npz whose train split is 40 shapes of the bundled sample."""
    with np.load(bundled_sample_path()) as sample:
        arrays = {key: sample[key] for key in sample.files}
    for key in ("points", "labels", "names"):
        arrays[f"train_{key}"] = arrays[f"test_{key}"][:40]
    np.savez(tmp_path / "tiny.npz", **arrays)
    return tmp_path / "tiny.npz"


def _train(data, out, *extra: str) -> list[str]:
    return [
        "train", "--data", str(data), "--output", str(out), "--num-points", "64",
        "--batch-size", "16", "--precision", "fp32", "--threads", "1", "--val-pairs", "8",
        "--model-config", '{"encoder_channels": [8, 16], "head_channels": [16, 8]}', *extra,
    ]  # fmt: skip


def test_the_printed_learning_rate_is_exact(tiny_data, tmp_path, capsys):
    assert main(_train(tiny_data, tmp_path / "run", "--epochs", "1", "--lr", "5e-5")) == 0
    err = capsys.readouterr().err
    assert "epoch 1: lr 5e-05," in err, err


def test_an_interrupt_says_where_the_run_is_and_how_to_resume(
    tiny_data, tmp_path, capsys, monkeypatch
):
    real_fit = masknet.training.fit

    def fit_then_interrupt(task, points, config, **kwargs):
        real_fit(task, points, config, **kwargs)  # one epoch saved, then Ctrl-C
        raise KeyboardInterrupt

    monkeypatch.setattr(masknet.training, "fit", fit_then_interrupt)
    out = tmp_path / "run"
    assert main(_train(tiny_data, out, "--epochs", "1")) == 130
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last == (
        f"masknet: interrupted; the last finished epoch is saved in {out / 'checkpoint.safetensors'}; "
        "run the same command with --resume to continue"
    )
    # Before any checkpoint exists, an interrupt says only that.
    monkeypatch.setattr(
        masknet.training, "fit", lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt)
    )
    assert main(_train(tiny_data, tmp_path / "fresh", "--epochs", "1")) == 130
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last == "masknet: interrupted; before the first epoch finished: nothing was saved"


def test_a_finished_run_says_how_to_use_its_weights(tiny_data, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(_train(tiny_data, out, "--epochs", "1")) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-2] == f"trained 1 epoch; best weights: {out / 'best.safetensors'}"
    assert lines[-1] == (
        f"use them: masknet evaluate, mask and register take --weights {out / 'best.safetensors'}"
    )

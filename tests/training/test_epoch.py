"""Stops within an epoch: SIGTERM saves where the run stands, and --resume goes on as if
nothing had happened (same batches, weights, running means and curve)."""

from __future__ import annotations

import os
import signal
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.training import MaskNetTask, TrainConfig, fit
from masknet.training.checkpoint import load_checkpoint

CROSS_TINY = {"channels": [8, 8, 16], "features": 16, "head_channels": [16], "keys": 32}


@pytest.fixture(scope="module")
def shapes() -> np.ndarray:
    return load_modelnet40(bundled_sample_path(), "test").points[:, :128]


@dataclass
class _StopsAt(MaskNetTask):
    """A MaskNet task that sends its own process SIGTERM during training step ``at``."""

    at: int = -1
    calls: int = 0

    def step(self, model, batch, device):
        if model.training:
            self.calls += 1
            if self.calls == self.at:
                os.kill(os.getpid(), signal.SIGTERM)
        return super().step(model, batch, device)


def _task(at: int = -1) -> _StopsAt:
    return _StopsAt(
        network="crossmasknet", loss="bce", num_points=128, model_config=CROSS_TINY, at=at
    )


def _config(out: Path, **changes) -> TrainConfig:
    settings = dict(
        out_dir=str(out),
        epochs=2,
        batch_size=16,
        lr=3e-3,
        precision="fp32",
        val_fraction=0.2,
        val_pairs=32,
        threads=1,
    )
    return TrainConfig(**(settings | changes))


def _weights(folder: Path) -> dict[str, torch.Tensor]:
    return load_file(str(folder / "last.safetensors"))


def test_sigterm_within_an_epoch_saves_and_resume_matches_an_unbroken_run(tmp_path, shapes):
    straight = fit(_task(), shapes, _config(tmp_path / "straight"))
    # Stop at the 3rd step of epoch 2 (6 steps an epoch), then resume.
    stopped = fit(_task(at=9), shapes, _config(tmp_path / "split"))
    assert [row["epoch"] for row in stopped] == [1]  # epoch 2 unfinished
    state = load_checkpoint(
        tmp_path / "split" / "checkpoint.safetensors",
        _task().build_model(),
        torch.optim.Adam(_task().build_model().parameters()),
    )
    assert state["epoch"] == 1 and state["progress"]["step"] == 3
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # handler restored
    resumed = fit(_task(), shapes, _config(tmp_path / "split"), resume=True)
    assert [row["epoch"] for row in resumed] == [1, 2]
    for key in ("train_loss", "train_precision", "val_loss", "val_precision"):
        assert resumed[1][key] == pytest.approx(straight[1][key], rel=1e-6), key
    a, b = _weights(tmp_path / "straight"), _weights(tmp_path / "split")
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert (tmp_path / "split" / "curve.png").stat().st_size > 0


def test_checkpoint_minutes_saves_within_an_epoch(tmp_path, shapes):
    # Saving after every step, then stopping at step 4: the checkpoint holds 4 steps.
    fit(_task(at=4), shapes, _config(tmp_path, epochs=1, checkpoint_minutes=1e-9))
    state = load_checkpoint(
        tmp_path / "checkpoint.safetensors",
        _task().build_model(),
        torch.optim.Adam(_task().build_model().parameters()),
    )
    assert state["epoch"] == 0 and state["progress"]["step"] == 4
    assert state["progress"]["count"] == 4 and state["progress"]["sums"]["loss"] > 0


def test_a_run_saved_within_an_epoch_may_change_its_checkpoint_interval(tmp_path, shapes):
    fit(_task(at=2), shapes, _config(tmp_path, epochs=1))
    history = fit(_task(), shapes, _config(tmp_path, epochs=1, checkpoint_minutes=5), resume=True)
    assert [row["epoch"] for row in history] == [1]


def test_a_run_stopped_before_it_saved_anything_leaves_no_folder(tmp_path, shapes):
    class Interrupted(_StopsAt):
        def step(self, model, batch, device):
            raise KeyboardInterrupt

    task = Interrupted(network="crossmasknet", loss="bce", num_points=128, model_config=CROSS_TINY)
    with pytest.raises(KeyboardInterrupt):
        fit(task, shapes, _config(tmp_path / "run"))
    assert not (tmp_path / "run").exists()

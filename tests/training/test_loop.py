"""The training loop: learning happens, checkpoints resume exactly, kills lose at most an epoch."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors import safe_open

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.errors import MaskNetError
from masknet.models import MaskNet
from masknet.training import MaskNetTask, RegistrationTask, TrainConfig, fit, split_train_val

TINY = {"encoder_channels": (16, 16, 32), "head_channels": (32, 16)}


@pytest.fixture(scope="module")
def shapes() -> np.ndarray:
    return load_modelnet40(bundled_sample_path(), "test").points[:, :128]


def _task() -> MaskNetTask:
    return MaskNetTask(num_points=128, model_config=TINY)


def _config(out: Path, epochs: int) -> TrainConfig:
    return TrainConfig(
        out_dir=str(out),
        epochs=epochs,
        batch_size=16,
        lr=3e-3,
        precision="fp32",
        val_fraction=0.2,
        threads=1,
    )


def test_split_is_disjoint_and_seeded():
    train, val = split_train_val(100, 0.1, seed=3)
    assert len(val) == 10 and len(train) == 90
    assert not set(train) & set(val)
    assert np.array_equal(split_train_val(100, 0.1, seed=3)[1], val)
    assert not np.array_equal(split_train_val(100, 0.1, seed=4)[1], val)


def test_fit_writes_log_checkpoint_and_weights(tmp_path, shapes):
    history = fit(_task(), shapes, _config(tmp_path, 3))
    assert [row["epoch"] for row in history] == [1, 2, 3]
    assert history[-1]["train_loss"] < history[0]["train_loss"]
    lines = (tmp_path / "log.csv").read_text().splitlines()
    assert lines[0].startswith("epoch,lr,train_loss") and len(lines) == 4
    model = MaskNet.from_file(tmp_path / "best.safetensors")
    assert model.encoder.out_channels == 32
    assert not list(tmp_path.glob("*.tmp"))


def test_resume_matches_uninterrupted_run(tmp_path, shapes):
    fit(_task(), shapes, _config(tmp_path / "straight", 2))
    fit(_task(), shapes, _config(tmp_path / "split", 1))
    history = fit(_task(), shapes, _config(tmp_path / "split", 2), resume=True)
    assert [row["epoch"] for row in history] == [1, 2]
    a = MaskNet.from_file(tmp_path / "straight" / "last.safetensors").state_dict()
    b = MaskNet.from_file(tmp_path / "split" / "last.safetensors").state_dict()
    for key in a:
        torch.testing.assert_close(a[key], b[key], rtol=1e-5, atol=1e-6)


def _registration_task() -> RegistrationTask:
    return RegistrationTask.for_network(
        "pointnetlk", num_points=64, iterations=2, model_config={"encoder_channels": [16, 32]}
    )


@pytest.mark.parametrize("make_task", [_task, _registration_task], ids=["masknet", "pointnetlk"])
def test_resume_continues_a_cosine_schedule_from_the_checkpoint(
    tmp_path, shapes, make_task, capsys
):
    """A 3-epoch cosine run stopped after epoch 1 (its time budget) and resumed:
    - ends exactly where the uninterrupted run ends, which needs the weights, Adam's
      moments and the schedule's step from the checkpoint;
    - runs only epochs 2 and 3, at the uninterrupted run's learning rates;
    - continues from the checkpoint's weights: perturb them, and the resumed run ends
      elsewhere, where a restart from scratch would still end on the uninterrupted run."""
    from safetensors.torch import load_file, save_file

    def config(out: str, minutes: float | None = None) -> TrainConfig:
        c = _config(tmp_path / out, 3)
        c.lr_schedule, c.max_minutes = "cosine", minutes
        return c

    def last(out: str) -> dict:
        with safe_open(str(tmp_path / out / "last.safetensors"), framework="pt") as f:
            return {k: f.get_tensor(k) for k in f.keys()}

    straight = fit(make_task(), shapes, config("straight"))
    for out in ("split", "perturbed"):
        assert len(fit(make_task(), shapes, config(out, minutes=1e-9))) == 1  # stops after 1
    capsys.readouterr()
    resumed = fit(make_task(), shapes, config("split"), resume=True)
    printed = capsys.readouterr().err
    assert "at epoch 2" in printed and "epoch 1:" not in printed and "epoch 3:" in printed
    assert [row["lr"] for row in resumed] == [row["lr"] for row in straight]
    assert resumed[1]["lr"] < resumed[0]["lr"]  # cosine: the schedule moved on
    a, b = last("straight"), last("split")
    for key in a:
        torch.testing.assert_close(a[key], b[key], rtol=1e-5, atol=1e-6)

    ckpt = tmp_path / "perturbed" / "checkpoint.safetensors"
    with safe_open(str(ckpt), framework="pt") as f:
        metadata = f.metadata()
    tensors = load_file(ckpt)
    first = next(k for k in tensors if k.startswith("model/") and tensors[k].is_floating_point())
    tensors[first] = tensors[first] + 0.5
    save_file(tensors, ckpt, metadata)
    fit(make_task(), shapes, config("perturbed"), resume=True)
    c = last("perturbed")
    assert max((a[k] - c[k]).abs().max().item() for k in a) > 1e-3


def test_existing_checkpoint_needs_resume(tmp_path, shapes):
    fit(_task(), shapes, _config(tmp_path, 1))
    with pytest.raises(MaskNetError, match="--resume"):
        fit(_task(), shapes, _config(tmp_path, 2))


def test_an_earlier_run_without_its_checkpoint_is_never_overwritten(tmp_path, shapes, capsys):
    fit(_task(), shapes, _config(tmp_path, 1))
    (tmp_path / "checkpoint.safetensors").unlink()
    before = (tmp_path / "best.safetensors").read_bytes()
    for resume in (False, True):
        with pytest.raises(MaskNetError, match="holds an earlier run .*best.safetensors"):
            fit(_task(), shapes, _config(tmp_path, 1), resume=resume)
    assert (tmp_path / "best.safetensors").read_bytes() == before
    # --resume on a folder with no run at all starts fresh, and says so.
    fit(_task(), shapes, _config(tmp_path / "new", 1), resume=True)
    assert f"no checkpoint in {tmp_path / 'new'}: starting a fresh run" in capsys.readouterr().err


def test_a_checkpoint_given_as_weights_points_to_best(tmp_path, shapes):
    fit(_task(), shapes, _config(tmp_path, 1))
    with pytest.raises(MaskNetError, match="a training checkpoint .* best.safetensors beside it"):
        MaskNet.from_file(tmp_path / "checkpoint.safetensors")


def test_resuming_a_finished_run_says_so(tmp_path, shapes, capsys):
    fit(_task(), shapes, _config(tmp_path, 1))
    capsys.readouterr()
    fit(_task(), shapes, _config(tmp_path, 1), resume=True)
    assert "already finished 1 of 1 epochs; raise --epochs" in capsys.readouterr().err


def _tiny_dataset(path: Path) -> Path:
    """A ModelNet40-style .npz whose train split is the bundled sample's shapes."""
    with np.load(bundled_sample_path()) as sample:
        arrays = {key: sample[key] for key in sample.files}
    arrays.update(
        {
            key.replace("test_", "train_"): arrays[key]
            for key in list(arrays)
            if key.startswith("test_")
        }
    )
    np.savez(path, **arrays)
    return path


def _train_cmd(data: Path, out: Path, epochs: int, *extra: str) -> list[str]:
    return [
        sys.executable,
        "-m",
        "masknet.cli",
        "train",
        "--data",
        str(data),
        "--output",
        str(out),
        "--epochs",
        str(epochs),
        "--num-points",
        "64",
        "--batch-size",
        "16",
        "--precision",
        "fp32",
        "--threads",
        "1",
        "--val-fraction",
        "0.2",
        "--val-pairs",
        "8",
        *extra,
    ]


def test_kill_mid_training_loses_at_most_one_epoch(tmp_path):
    """SIGKILL the CLI after an epoch has been saved, then --resume finishes with a complete log."""
    data, out = _tiny_dataset(tmp_path / "tiny.npz"), tmp_path / "run"
    proc = subprocess.Popen(
        _train_cmd(data, out, 40), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    deadline = time.time() + 180
    while not (out / "log.csv").exists() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done = len((out / "log.csv").read_text().splitlines()) - 1
    assert 1 <= done < 40
    resumed = subprocess.run(
        _train_cmd(data, out, done + 1, "--resume"), capture_output=True, text=True, timeout=300
    )
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    rows = (out / "log.csv").read_text().splitlines()[1:]
    assert [int(r.split(",")[0]) for r in rows] == list(range(1, done + 2))
    # the best weights are one of the epochs' (the best validation precision in the log)
    best = MaskNet.from_file(out / "best.safetensors")
    last = MaskNet.from_file(out / "last.safetensors")
    header = (out / "log.csv").read_text().splitlines()[0].split(",")
    precision = [float(r.split(",")[header.index("val_precision")]) for r in rows]
    pairs = zip(best.state_dict().values(), last.state_dict().values(), strict=True)
    same = all(torch.equal(a, b) for a, b in pairs)
    assert same == (precision[-1] >= max(precision))


@pytest.mark.parametrize(
    ("changes", "needle"),
    [
        ({"batch_size": 200}, "fewer than one batch"),
        ({"val_fraction": 1.5}, "--val-fraction"),
        ({"device": "bogus"}, "unknown device"),
    ],
)
def test_bad_config_is_refused_before_writing(tmp_path, shapes, changes, needle):
    config = _config(tmp_path / "run", 1)
    for key, value in changes.items():
        setattr(config, key, value)
    with pytest.raises(MaskNetError, match=needle):
        fit(_task(), shapes, config)
    assert not (tmp_path / "run").exists()


def test_resume_with_other_settings_is_refused(tmp_path, shapes):
    fit(_task(), shapes, _config(tmp_path, 1))
    changed = _config(tmp_path, 2)
    changed.seed = 1  # would move training shapes into validation
    with pytest.raises(MaskNetError, match="seed"):
        fit(_task(), shapes, changed, resume=True)
    longer = fit(_task(), shapes, _config(tmp_path, 2), resume=True)  # epochs may change
    assert len(longer) == 2


def test_corrupt_checkpoint_is_one_clear_error(tmp_path, shapes):
    fit(_task(), shapes, _config(tmp_path, 1))
    (tmp_path / "checkpoint.safetensors").write_bytes(b"not a checkpoint")
    with pytest.raises(MaskNetError, match="cannot resume"):
        fit(_task(), shapes, _config(tmp_path, 2), resume=True)


def test_pointnetlk_trains_and_exports_loadable_weights(tmp_path):
    from masknet.models import PointNetLK
    from masknet.training import RegistrationTask

    shapes = load_modelnet40(bundled_sample_path()).points[:40]
    task = RegistrationTask.for_network(
        "pointnetlk", num_points=64, iterations=2, model_config={"encoder_channels": [16, 32]}
    )
    config = TrainConfig(
        out_dir=str(tmp_path), epochs=2, batch_size=8, precision="fp32", val_pairs=8, lr=1e-3
    )
    history = fit(task, shapes, config)
    assert [row["epoch"] for row in history] == [1, 2]
    assert all(np.isfinite(row["val_rotation_error_deg"]) for row in history)
    model = PointNetLK.from_file(tmp_path / "best.safetensors")
    assert model.config["encoder_channels"] == [16, 32]
    # best = lowest validation error (the task minimises its metric)
    best_epoch = min(history, key=lambda row: row["val_rotation_error_deg"])["epoch"]
    from safetensors import safe_open

    with safe_open(str(tmp_path / "best.safetensors"), framework="pt") as f:
        assert json.loads(f.metadata()["epoch"]) == best_epoch


@pytest.mark.parametrize(
    "name, config",
    [
        ("dcp", {"channels": [8, 16], "embedding": 16, "k": 8, "heads": 2, "feedforward": 32}),
        ("prnet", {"channels": [8, 16], "embedding": 16, "k": 8, "heads": 2, "feedforward": 32}),
        ("pcrnet", {"encoder_channels": [16, 32], "head_channels": [32, 16]}),
        ("rpmnet", {"features": 16, "k": 8, "parameter_channels": [16, 32]}),
    ],
)
def test_registration_networks_train_and_export(tmp_path, name, config):
    from masknet.models import REGISTRATION_NETWORKS

    shapes = load_modelnet40(bundled_sample_path()).points[:24]
    task = RegistrationTask.for_network(name, num_points=64, model_config=config)
    train_config = TrainConfig(
        out_dir=str(tmp_path), epochs=1, batch_size=8, precision="fp32", val_pairs=8, lr=1e-3
    )
    history = fit(task, shapes, train_config)
    assert np.isfinite(history[-1]["train_loss"]) and np.isfinite(
        history[-1]["val_rotation_error_deg"]
    )
    model = REGISTRATION_NETWORKS[name].from_file(tmp_path / "best.safetensors")
    assert model.config == {**REGISTRATION_NETWORKS[name]().config, **config}


def test_bce_trains_a_saturated_network_out_of_keeping_everything(shapes):
    """A MaskNet whose sigmoid is saturated at 1 for every point (the keep-everything
    start of a denoising run) still gets a gradient from BCE, which works on logits;
    BCE on clamped scores would give exactly none."""
    from masknet.data import PairConfig, make_test_pairs

    torch.manual_seed(0)
    model = MaskNet(encoder_channels=[8, 16], head_channels=[16, 8])
    with torch.no_grad():
        model.head[-1].bias.fill_(40.0)  # sigmoid(40) == 1.0 in float32
    pairs = make_test_pairs(shapes[:4], 4, PairConfig(outlier_ratio=0.2), seed=0)
    assert (model(pairs.source, pairs.template) == 1.0).all()
    task = MaskNetTask.denoising(PairConfig(outlier_ratio=0.2), loss="bce")
    loss, metrics = task.step(model, pairs, torch.device("cpu"))
    loss.backward()
    assert model.head[-1].bias.grad.abs().item() > 0.1  # ~ the outlier share, 1/6
    assert metrics["recall"] == 1.0 and metrics["precision"] < 0.9  # keeps the outliers too


def test_checkpoint_holds_no_pickle_and_an_earlier_pt_checkpoint_still_resumes(tmp_path, shapes):
    fit(_task(), shapes, _config(tmp_path, 1))
    raw = (tmp_path / "checkpoint.safetensors").read_bytes()
    assert b"\x80\x04" not in raw[:64] and (tmp_path / "checkpoint.safetensors").stat().st_size
    # The same run state written the way earlier versions did (torch.save) resumes too.
    model, legacy = MaskNet(**TINY), tmp_path / "legacy"
    legacy.mkdir()
    optimizer = torch.optim.Adam(model.parameters())
    from masknet.training.checkpoint import load_checkpoint

    state = load_checkpoint(tmp_path / "checkpoint.safetensors", model, optimizer)
    torch.save(
        {"model": model.state_dict(), "optimizer": optimizer.state_dict(), **state},
        legacy / "checkpoint.pt",
    )
    history = fit(_task(), shapes, _config(legacy, 2), resume=True)
    assert [row["epoch"] for row in history] == [1, 2]
    assert (legacy / "checkpoint.safetensors").exists()

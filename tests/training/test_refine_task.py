"""Training the refinement mask: residual poses, both masks, resumable, fine-tunable."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.data.pairs import PairConfig
from masknet.data.residuals import ResidualConfig
from masknet.data.scans import Scan, ScanCropConfig
from masknet.data.views import ViewConfig
from masknet.errors import MaskNetError
from masknet.geometry.se3 import transform_points
from masknet.models.refine import RefineMaskNet
from masknet.training import TrainConfig, fit
from masknet.training.refine_task import RefineMaskTask
from masknet.training.scan_mix import ScanMix

SMALL = {"k": 6, "local_channels": [8, 16], "point_channels": [16, 32], "head_channels": [16]}


def _scan(name: str, seed: int) -> Scan:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-2, 2, (2000, 2))
    points = np.column_stack([xy, 0.3 * np.sin(2 * xy[:, 0])]).astype(np.float32)
    return Scan(name, points)


MIX_FIELDS = {f.name for f in dataclasses.fields(ScanMix)}


def _task(**changes) -> RefineMaskTask:
    settings = dict(
        pairs=PairConfig(),
        num_points=128,
        model_config=SMALL,
        scans=[_scan("a", 0), _scan("b", 1)],
        val_scans=[_scan("c", 2)],
        view=ViewConfig(template_points=64, noise_sigma=0.01, random_noise=True),
        crop=ScanCropConfig(crop_points=(256, 512)),
        scan_batches=2,
        modelnet_fraction=1.0,
        modelnet_view_fraction=0.5,
        modelnet_view_points=48,
    )
    settings |= changes
    mix = ScanMix(**{k: v for k, v in settings.items() if k in MIX_FIELDS})
    return RefineMaskTask(mix=mix, **{k: v for k, v in settings.items() if k not in MIX_FIELDS})


@pytest.fixture(scope="module")
def shapes() -> np.ndarray:
    return load_modelnet40(bundled_sample_path(), "test").points[:, :128]


def test_batches_are_near_their_templates_by_a_residual(shapes):
    task = _task(residual=ResidualConfig(near_fraction=1.0, wide_fraction=0.0, near_deg=2.0))
    batch = next(iter(task.train_batches(shapes, 16, seed=0, epoch=0)))
    # the transform left to find is small: applying it moves the source by little
    back = transform_points(batch.transform.double(), batch.source.double())
    moved = (back - batch.source.double()).norm(dim=-1).mean()
    assert float(moved) < 0.15
    assert not batch.source_mask.all()  # the two-sided task's corruption is there


def test_step_scores_both_masks(shapes):
    task = _task()
    torch.manual_seed(0)
    model = task.build_model()
    batch = next(iter(task.train_batches(shapes, 16, seed=0, epoch=0)))
    loss, metrics = task.step(model, batch, torch.device("cpu"))
    assert loss.requires_grad and loss.item() > 0
    for key in ("template_precision", "template_recall", "source_f1", "score"):
        assert 0 <= metrics[key] <= 1, key
    assert metrics["score"] == pytest.approx(
        (metrics["template_precision"] + metrics["source_f1"]) / 2
    )


def test_fit_trains_resumes_and_fine_tunes(tmp_path, shapes):
    config = TrainConfig(
        out_dir=str(tmp_path / "run"),
        epochs=1,
        batch_size=16,
        lr=3e-3,
        precision="fp32",
        val_fraction=0.2,
        val_pairs=16,
        threads=1,
    )
    history = fit(_task(), shapes, config)
    assert 0 < history[0]["val_score"] <= 1 and "val_scans_source_f1" in history[0]
    config.epochs = 2
    history = fit(_task(), shapes, config, resume=True)
    assert [r["epoch"] for r in history] == [1, 2]
    best = tmp_path / "run" / "best.safetensors"
    trained = RefineMaskNet.from_file(best)
    assert trained.config["point_channels"] == SMALL["point_channels"]
    tuned = _task(init=str(best)).build_model()
    for a, b in zip(tuned.state_dict().values(), trained.state_dict().values(), strict=True):
        assert torch.equal(a, b)  # --init starts from the file's weights


def test_fine_tuning_with_a_context_stage_widens_the_weights_it_starts_from(tmp_path, shapes):
    torch.manual_seed(0)
    narrow = RefineMaskNet(**SMALL).eval()
    path = tmp_path / "narrow.safetensors"
    narrow.save(path)
    wide = _task(init=str(path), model_config={**SMALL, "context": 8}).build_model().eval()
    assert wide.config["context"] == 8
    template, source = shapes[0], shapes[0][:100]
    np.testing.assert_allclose(
        wide.predict(template, source)[0], narrow.predict(template, source)[0], atol=1e-6
    )
    same = _task(init=str(path)).build_model()  # no context asked: the file's own architecture
    assert "context" not in same.config
    # An architecture that differs from the file's is refused, not silently ignored.
    wide_path = tmp_path / "wide.safetensors"
    wide.save(wide_path)
    for config in ({"context": 16}, {**SMALL, "k": 4}):
        with pytest.raises(MaskNetError, match="differs from the --init weights"):
            _task(init=str(wide_path), model_config=config).build_model()
    assert _task(init=str(wide_path), model_config={"context": 8}).build_model().config == (
        wide.config
    )
    as_tuples = {key: tuple(v) if isinstance(v, list) else v for key, v in SMALL.items()}
    assert _task(init=str(wide_path), model_config=as_tuples).build_model().config == (
        wide.config  # the same architecture, given as tuples
    )

"""masknet evaluate: the JSON report, and what to download when the data is missing."""

from __future__ import annotations

import json

import pytest

from masknet.cli import main
from masknet.data import bundled_sample_path


def test_evaluate_json(tmp_path, small_masknet_weights, capsys):
    out = tmp_path / "r.json"
    args = [
        "evaluate",
        "--data",
        str(bundled_sample_path()),
        "--pairs",
        "40",
        "--seed",
        "3",
        "--weights",
        str(small_masknet_weights),
        "--output",
        str(out),
    ]
    assert main(args) == 0
    result = json.loads(out.read_text())
    assert result["pairs"] == 40 and result["seed"] == 3
    top_k = result["metrics"]["top-k (k=M)"]
    assert 0 <= top_k["precision"] <= 1 and top_k["precision"] == pytest.approx(top_k["recall"])
    assert 0 < result["topk_precision_stderr"] < 0.1
    printed = capsys.readouterr().out
    assert "random top-k" in printed and "standard error of the mean" in printed


def test_evaluate_missing_data_says_what_to_download(monkeypatch, capsys):
    monkeypatch.delenv("MASKNET_DATA", raising=False)
    assert main(["evaluate", "--pairs", "5"]) == 2
    assert "modelnet40_ply_hdf5_2048" in capsys.readouterr().err


def test_evaluate_and_mask_take_crossmasknet_weights(tmp_path, pair_files, capsys):
    """A CrossMaskNet file (masknet train --model crossmasknet) is read by its metadata and
    answers as MaskNet does: evaluate scores it, mask writes its top-k mask."""
    from masknet.models import CrossMaskNet

    weights = tmp_path / "cross.safetensors"
    CrossMaskNet(channels=[8, 8, 16], features=16, head_channels=[16], keys=32).save(weights)
    out = tmp_path / "r.json"
    data = str(bundled_sample_path())
    args = ["evaluate", "--data", data, "--pairs", "8", "--weights", str(weights), "-o", str(out)]
    assert main(args) == 0
    assert json.loads(out.read_text())["weights"].endswith("cross.safetensors")
    template, source, _ = pair_files
    mask_out = tmp_path / "kept.xyz"
    args = ["mask", str(template), str(source), "-o", str(mask_out), "--weights", str(weights)]
    assert main(args) == 0
    assert mask_out.exists() and (tmp_path / "kept_mask.txt").exists()

"""masknet demo: the picture and the metrics."""

from __future__ import annotations

import json

from masknet.cli import main


def test_demo_writes_picture_and_metrics(tmp_path, small_masknet_weights, capsys):
    assert (
        main(
            [
                "demo",
                "--output",
                str(tmp_path),
                "--pairs",
                "16",
                "--weights",
                str(small_masknet_weights),
            ]
        )
        == 0
    )
    png = (tmp_path / "masknet_demo.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000
    assert json.loads((tmp_path / "metrics.json").read_text())["pairs"] == 16
    assert "top-k (k=M)" in capsys.readouterr().out

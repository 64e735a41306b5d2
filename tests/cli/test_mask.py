"""masknet mask: inliers and mask files, the threshold rule, one line per input row."""

from __future__ import annotations

import numpy as np

from masknet.cli import main


def test_mask_writes_inliers_and_mask(tmp_path, small_masknet_weights, pair_files, capsys):
    template, source, pair = pair_files
    out = tmp_path / "inliers.xyz"
    assert (
        main(
            [
                "mask",
                str(template),
                str(source),
                "-o",
                str(out),
                "--weights",
                str(small_masknet_weights),
            ]
        )
        == 0
    )
    mask = np.loadtxt(tmp_path / "inliers_mask.txt", dtype=int)
    assert mask.shape == (1024,) and mask.sum() == pair.source.shape[1]
    kept = np.loadtxt(out)
    np.testing.assert_allclose(kept, pair.template[0].numpy()[mask.astype(bool)], atol=1e-6)
    assert "kept 717 of 1024" in capsys.readouterr().out


def test_mask_threshold_rule(tmp_path, small_masknet_weights, pair_files):
    template, source, _ = pair_files
    out = tmp_path / "t.npy"
    args = [
        "mask",
        str(template),
        str(source),
        "-o",
        str(out),
        "--weights",
        str(small_masknet_weights),
        "--threshold",
        "1",
    ]
    assert main(args) == 0
    assert np.load(out).shape == (0, 3)  # no score of this small network reaches 1


def test_mask_files_have_a_line_per_input_row_after_drop_nonfinite(tmp_path, pair_files):
    template, source, _ = pair_files
    points = np.loadtxt(template)
    points[[3, 10]] = np.nan
    np.savetxt(tmp_path / "t.xyz", points)
    out = tmp_path / "m.xyz"
    args = ["mask", str(tmp_path / "t.xyz"), str(source), "-o", str(out), "--drop-nonfinite"]
    assert main(args) == 0
    mask = np.loadtxt(tmp_path / "m_mask.txt")
    assert mask.shape == (len(points),) and mask[3] == 0 and mask[10] == 0
    np.testing.assert_allclose(np.loadtxt(out).reshape(-1, 3), points[mask.astype(bool)], atol=1e-6)


def test_mask_warns_when_the_default_would_keep_the_whole_template(
    tmp_path, small_masknet_weights, pair_files, capsys
):
    template, source, _ = pair_files  # given the other way round: source is the full cloud
    out = tmp_path / "kept.xyz"
    args = ["mask", str(source), str(template), "-o", str(out)]
    assert main([*args, "--weights", str(small_masknet_weights)]) == 0
    captured = capsys.readouterr()
    assert "SOURCE has 1024 points and TEMPLATE 717" in captured.err
    assert "kept 717 of 717" in captured.out
    assert main([*args, "--k", "300", "--weights", str(small_masknet_weights)]) == 0
    assert "warning" not in capsys.readouterr().err

"""The masknet command as a whole: help, refusals on one line, options and their help."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from masknet.cli import main
from masknet.data import bundled_sample_path, load_modelnet40
from masknet.io import read_points


@pytest.mark.parametrize(
    ("content", "name", "needle"),
    [
        (None, "missing.xyz", "missing.xyz"),
        ("1 2 3\nnan 0 0\n4 5 6\n7 8 9\n", "nan.xyz", "NaN"),
        ("1 2\n3 4\n5 6\n", "flat.xyz", "flat.xyz"),
        ("1 2 3\n", "few.xyz", "few.xyz"),
        ("hello", "cloud.foo", "cloud.foo"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(
    tmp_path, small_masknet_weights, pair_files, content, name, needle
):
    template, _, _ = pair_files
    bad = tmp_path / name
    if content is not None:
        bad.write_text(content)
    out = tmp_path / "out.ply"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "masknet.cli",
            "mask",
            str(template),
            str(bad),
            "-o",
            str(out),
            "--weights",
            str(small_masknet_weights),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("masknet: error:") and needle in lines[0], (
        proc.stderr
    )
    assert "Traceback" not in proc.stderr
    assert list(tmp_path.glob("out*")) == []


def test_unknown_pretrained_name_is_clear(capsys):
    assert main(["demo", "--weights", "nope"]) == 2
    assert "no shipped MaskNet weights named 'nope'" in capsys.readouterr().err


@pytest.mark.parametrize(
    "args",
    [
        ["evaluate", "--pairs", "0"],
        ["train", "--output", "x", "--batch-size", "0"],
        ["train", "--output", "x", "--seed", "-1"],
        ["mask", "a.xyz", "b.xyz", "-o", "c.xyz", "--k", "0"],
        ["mask", "a.xyz", "b.xyz", "-o", "c.xyz", "--threshold", "nan"],
    ],
)
def test_bad_numbers_are_rejected_by_the_parser(args, capsys):
    with pytest.raises(SystemExit) as exc:
        main(args)
    assert exc.value.code == 2
    assert "error: argument" in capsys.readouterr().err


def test_help_does_not_import_torch_and_names_agree():
    code = "import sys, masknet.cli; masknet.cli.build_parser(); print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
    from masknet.models import REGISTRATION_NETWORKS
    from masknet.registration.terms.methods import METHOD_TITLES, METHODS, NETWORK_METHODS

    assert NETWORK_METHODS == tuple(REGISTRATION_NETWORKS)
    assert set(METHODS) == set(METHOD_TITLES)


def test_help_lists_what_to_run_first_one_line_each(monkeypatch):
    from masknet.cli import COMMANDS, build_parser

    monkeypatch.setenv("COLUMNS", "80")  # argparse wraps at the terminal's width
    text = build_parser().format_help()
    listed = text.split("\ncommands:\n", 1)[1].splitlines()[1:]  # after "COMMAND"
    names = [line.split()[0] for line in listed]
    assert names[:2] == ["register", "mask"]  # what a newcomer runs first
    assert names.index("train") > names.index("demo") and names[-1] == "make-sample"
    # One line each, a description beside every name (none wraps onto its own line).
    assert all(line.startswith("    ") and len(line.split()) > 2 for line in listed)
    assert len(listed) == len(COMMANDS) == 11 and "masknet register TEMPLATE SOURCE" in text


def test_an_unwritable_viewer_path_fails_before_anything_is_written(tmp_path, pair_files, capsys):
    template, source, _ = pair_files
    blocker = tmp_path / "plain_file"
    blocker.write_text("x")
    args = ["register", str(template), str(source), "-o", str(tmp_path / "ok.npy")]
    assert main([*args, "--html", str(blocker / "v.html")]) == 2
    assert "not a writable directory" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plain_file"]
    if Path("/proc").is_dir():
        assert main([*args, "--html", "/proc/v.html"]) == 2
        assert sorted(p.name for p in tmp_path.iterdir()) == ["plain_file"]


def test_every_option_of_every_command_has_help_text():
    import argparse

    from masknet.cli import build_parser

    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    missing = [
        f"{name} {action.option_strings or action.dest}"
        for name, sub in commands.choices.items()
        for action in sub._actions
        if not isinstance(action, argparse._HelpAction) and not action.help
    ]
    assert missing == []


def test_viewer_names_and_thresholds_are_checked_first(tmp_path, pair_files, capsys):
    template, source, _ = pair_files
    out = tmp_path / "o.ply"
    base = [str(template), str(source), "-o", str(out)]
    assert main(["register", *base, "--html", str(tmp_path / "o_inliers.ply")]) == 2
    assert "the viewer is an .html file" in capsys.readouterr().err
    assert main(["mask", *base, "--threshold", "2"]) == 2
    assert "--threshold must be in [0, 1]" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_colour_and_normals_pass_through_to_the_outputs(tmp_path, capsys, o3d):
    """PLY/PCD inputs with colour and normals: the registered source keeps its colours and
    has its normals turned by R; the inliers, the mask and the denoised points keep theirs."""
    from masknet.io import read_point_attributes

    rng = np.random.default_rng(0)
    shape = load_modelnet40(bundled_sample_path(), "test").points[0].astype(np.float64)
    rot = Rotation.from_euler("z", 20, degrees=True).as_matrix()

    def save(path, points, colors, normals):
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        cloud.colors = o3d.utility.Vector3dVector(colors)
        cloud.normals = o3d.utility.Vector3dVector(normals)
        o3d.io.write_point_cloud(str(path), cloud)

    normals = shape / np.linalg.norm(shape, axis=1, keepdims=True)
    colors = rng.random((len(shape), 3))
    part = shape[:, 0] > -0.3
    save(tmp_path / "t.ply", shape, colors, normals)
    save(tmp_path / "s.pcd", shape[part] @ rot.T, colors[part], normals[part] @ rot.T)
    assert (
        main(
            [
                "register",
                str(tmp_path / "t.ply"),
                str(tmp_path / "s.pcd"),
                "-o",
                str(tmp_path / "m.ply"),
            ]
        )
        == 0
    )
    moved = read_point_attributes(tmp_path / "m.ply")
    np.testing.assert_allclose(moved.colors, colors[part], atol=1 / 255)
    np.testing.assert_allclose(moved.normals, normals[part], atol=1e-4)  # turned back by R
    inliers = read_point_attributes(tmp_path / "m_inliers.ply")
    kept = read_points(tmp_path / "m_inliers.ply")
    index = cKDTree(shape).query(kept)[1]
    np.testing.assert_allclose(inliers.colors, colors[index], atol=1 / 255)
    np.testing.assert_allclose(inliers.normals, normals[index], atol=1e-6)
    assert (
        main(
            [
                "denoise",
                str(tmp_path / "t.ply"),
                str(tmp_path / "t.ply"),
                "-o",
                str(tmp_path / "d.pcd"),
            ]
        )
        == 0
    )
    np.testing.assert_allclose(
        read_point_attributes(tmp_path / "d.pcd").colors, colors, atol=1 / 255
    )
    capsys.readouterr()


def test_the_command_exits_with_mains_code_and_ignores_a_late_ctrl_c(monkeypatch):
    """Once main has returned (outputs written, code decided), a Ctrl-C in the exit must not
    turn the run into a silent 130."""
    import signal

    import masknet.cli as cli

    monkeypatch.setattr(cli, "main", lambda: 3)
    before = signal.getsignal(signal.SIGINT)
    try:
        with pytest.raises(SystemExit) as done:
            cli.entry()
        assert done.value.code == 3
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, before)

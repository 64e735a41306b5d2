"""masknet register's conventions: the exit-status table, no abbreviated options, a start
matrix read from a file, the cut-off flag, and what Ctrl-C leaves behind."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from masknet.cli import build_parser, main
from masknet.cli._common import (
    EXIT_CODES,
    progress,
)
from masknet.cli._outputs import _can_create_in
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("register")
    shapes = load_modelnet40(bundled_sample_path(), "test").points[:1]
    pair = make_test_pairs(shapes, 1, PairConfig(), seed=4)
    np.savetxt(folder / "template.xyz", pair.template[0].numpy())
    np.save(folder / "source.npy", pair.source[0].numpy())
    return folder / "template.xyz", folder / "source.npy"


def test_the_exit_codes_are_in_help_and_in_the_readme(capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["register", "--help"])
    shown = capsys.readouterr().out
    readme = (ROOT / "README.md").read_text()
    for code, meaning in EXIT_CODES.items():
        assert re.search(rf"^\s+{code}\s+{re.escape(meaning[:40])}", shown, re.M), code
        assert f"| {code} |" in readme, f"README has no row for exit status {code}"


def test_a_long_option_is_never_abbreviated(files, tmp_path, capsys):
    template, source = files
    args = ["register", str(template), str(source), "-o", str(tmp_path / "m.xyz")]
    with pytest.raises(SystemExit) as stop:
        build_parser().parse_args([*args, "--max-iteration", "5"])
    assert stop.value.code == 2
    assert "unrecognized arguments: --max-iteration" in capsys.readouterr().err
    assert not (tmp_path / "m.xyz").exists()


def test_init_reads_a_matrix_file_and_refuses_a_bad_one(files, tmp_path, capsys):
    template, source = files
    out = tmp_path / "moved.xyz"
    args = [
        "register",
        str(template),
        str(source),
        "-o",
        str(out),
        "--exit-zero",
        "--method",
        "icp",
    ]
    assert main([*args, "--init", "identity"]) == 0
    identity = np.loadtxt(tmp_path / "moved_transform.txt")
    np.save(tmp_path / "eye.npy", np.eye(4))
    assert main([*args, "--init", str(tmp_path / "eye.npy")]) == 0
    np.testing.assert_allclose(np.loadtxt(tmp_path / "moved_transform.txt"), identity, atol=1e-9)
    capsys.readouterr()
    (tmp_path / "bad.txt").write_text("1 2 3\n4 5 6\n")
    for bad in (str(tmp_path / "bad.txt"), str(tmp_path / "missing.txt")):
        with pytest.raises(SystemExit) as stop:
            build_parser().parse_args([*args, "--init", bad])
        assert stop.value.code == 2
        err = capsys.readouterr().err
        assert "--init" in err and len(err.strip().splitlines()) == 1


def test_the_cut_off_flag_is_refused_where_the_method_has_none(files, tmp_path, capsys):
    template, source = files
    args = ["register", str(template), str(source), "-o", str(tmp_path / "m.xyz")]
    assert main([*args, "--method", "pointnetlk", "--max-correspondence-distance", "0.1"]) == 2
    assert "unknown option(s) for method 'pointnetlk': max_correspondence_distance" in (
        capsys.readouterr().err
    )
    assert main([*args, "--max-correspondence-distance", "-1"]) == 2
    assert not (tmp_path / "m.xyz").exists()


def test_an_interrupted_step_is_not_called_done(capsys):
    with pytest.raises(KeyboardInterrupt), progress("a long step", after=0.0):
        import time

        time.sleep(0.05)  # the announcement is printed
        raise KeyboardInterrupt
    err = capsys.readouterr().err
    assert "a long step ..." in err and "done" not in err


def test_the_writability_probe_leaves_nothing(tmp_path):
    assert _can_create_in(tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_method_options_k_and_threshold_have_flags(files, tmp_path, capsys):
    from masknet import register
    from masknet.io import read_points

    template, source = files
    out = tmp_path / "m.xyz"
    args = ["register", str(template), str(source), "-o", str(out), "--exit-zero"]
    assert main([*args, "--method", "icp", "--option", "relative_rmse=0.01", "--k", "300"]) == 0
    expected = register(
        read_points(template), read_points(source), method="icp", relative_rmse=0.01, k=300
    )
    np.testing.assert_allclose(
        np.loadtxt(tmp_path / "m_transform.txt"), expected.transform, atol=1e-8
    )
    assert "inliers: 300 of" in capsys.readouterr().out
    assert main([*args, "--method", "icp", "--mask-threshold", "0.5"]) == 0
    assert "Mask-ICP" in capsys.readouterr().out
    assert main([*args, "--option", "no_such_field=1"]) == 2
    assert "unknown option(s) for method 'auto': no_such_field" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        build_parser().parse_args([*args, "--option", "nonsense"])
    with pytest.raises(SystemExit):
        build_parser().parse_args([*args, "--k", "5", "--mask-threshold", "0.5"])

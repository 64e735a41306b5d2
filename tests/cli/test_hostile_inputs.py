"""Hostile inputs, one table: every bad file through the command line and the API.

Each case must end in exit code 2 with one line ``masknet: error: <file>: <problem>``
(no traceback), write no output, and delete nothing; the API raises MaskNetError with
the same message. Fuzzed, truncated and bit-flipped PLY, PCD and NPY files either read
as a finite (N, 3) cloud or fail the same way.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from masknet.cli import main
from masknet.errors import MaskNetError
from masknet.io import read_points, write_points

RNG = np.random.default_rng(0)
GOOD = RNG.random((300, 3))
HEADER = "ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\n"


def _ascii_ply(points: np.ndarray, declared: int) -> str:
    body = "\n".join(" ".join(f"{v:.5f}" for v in p) for p in points)
    return HEADER.format(n=declared) + "property float z\nend_header\n" + body + "\n"


def _nan_rows() -> np.ndarray:
    points = GOOD[:50].copy()
    points[7] = np.nan
    return points


# name -> (how to make the file in a folder, the message it must give)
CASES = {
    "missing.npy": (lambda p: None, "no such file"),
    "folder.npy": (lambda p: p.mkdir(), "is a directory"),
    "empty.ply": (lambda p: p.write_bytes(b""), "empty file"),
    "cloud.foo": (lambda p: p.write_text("1 2 3\n"), "unsupported extension '.foo'"),
    "nan.npy": (lambda p: np.save(p, _nan_rows()), "1 row contains NaN or inf"),
    "two.npy": (lambda p: np.save(p, GOOD[:2]), "only 2 point(s)"),
    "flat.npy": (lambda p: np.save(p, GOOD[:, :2]), "expected an (N, 3) array"),
    "text.npy": (lambda p: np.save(p, GOOD.astype(str)), "expected numbers"),
    "bools.npy": (lambda p: np.save(p, GOOD > 0.5), "expected numbers"),
    "same.npy": (lambda p: np.save(p, np.ones((30, 3))), "all 30 points are identical"),
    "line.npy": (lambda p: np.save(p, np.outer(np.arange(30.0), [1, 2, 3])), "lie on one line"),
    "huge.npy": (lambda p: np.save(p, GOOD * 1e39), "beyond float32"),
    "lying.ply": (
        lambda p: p.write_text(_ascii_ply(GOOD, declared=100)),
        "the PLY header declares 100 vertices but the body has 300 rows",
    ),
    "garbage.npy": (lambda p: p.write_bytes(b"\x93NUMPY garbage"), "not a valid, readable .npy"),
    # No NumPy header: numpy would take it for a pickle and suggest allow_pickle.
    "text_as.npy": (lambda p: p.write_text("1 2 3\n4 5 6\n"), "not a .npy file (no NumPy header)"),
    # One line of words is no header over numbers.
    "words.xyz": (lambda p: p.write_text("hello world foo\n"), "cannot parse as numbers"),
}


@pytest.fixture(scope="module")
def good_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("good") / "good.npy"
    np.save(path, GOOD)
    return path


def _make(folder: Path, name: str) -> Path:
    path = folder / name
    CASES[name][0](path)
    return path


@pytest.mark.parametrize("name", list(CASES))
def test_bad_file_through_the_api(tmp_path, name):
    path = _make(tmp_path, name)
    with pytest.raises(MaskNetError) as info:
        read_points(path)
    message = str(info.value)
    assert message.startswith(str(path)) and CASES[name][1] in message and "\n" not in message


@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.parametrize("command", ["register", "mask", "denoise"])
def test_bad_file_through_the_cli(tmp_path, good_file, capsys, name, command):
    path = _make(tmp_path, name)
    out = tmp_path / "out" / "result.npy"
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "result.npy").write_text("EARLIER")
    assert main([command, str(good_file), str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"masknet: error: {path}")
    assert CASES[name][1] in err[0]
    # nothing written, nothing deleted
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["result.npy"]
    assert out.read_text() == "EARLIER"


def test_api_register_refuses_non_numeric_clouds():
    from masknet import register

    with pytest.raises(MaskNetError, match="source: expected numbers"):
        register(GOOD, GOOD.astype(str))


@pytest.mark.parametrize("kind", ["binary.ply", "ascii.ply", "binary.pcd", "array.npy"])
def test_fuzzed_truncated_and_bit_flipped_files_fail_cleanly(tmp_path, kind, o3d):
    ext = kind[kind.index(".") :]
    source = tmp_path / f"valid{ext}"
    if kind == "ascii.ply":
        source.write_text(_ascii_ply(GOOD[:200], declared=200))
    elif kind == "array.npy":
        np.save(source, GOOD[:200])
    else:
        write_points(source, GOOD[:200])
    raw = source.read_bytes()
    rng = np.random.default_rng(len(kind))
    for trial in range(40):
        data = bytearray(raw)
        if trial % 2:  # truncated
            data = data[: int(rng.integers(0, len(raw)))]
        else:  # bits flipped, mostly in the header
            for _ in range(3):
                i = int(rng.integers(0, min(len(data), 300)))
                data[i] ^= 1 << int(rng.integers(0, 8))
        path = tmp_path / f"fuzzed{ext}"
        path.write_bytes(bytes(data))
        try:
            points = read_points(path)
        except MaskNetError as exc:
            assert str(path) in str(exc) and "\n" not in str(exc)
        else:
            assert points.ndim == 2 and points.shape[1] == 3 and np.isfinite(points).all()


SIDE_FILE = {"register": "_transform.txt", "mask": "_mask.txt", "denoise": "_mask.txt"}


@pytest.mark.parametrize("command", ["register", "mask", "denoise"])
@pytest.mark.parametrize("kind", ["same path", "symbolic link", "hard link", "side file"])
def test_an_output_that_is_an_input_is_refused_before_any_work(
    tmp_path, capsys, monkeypatch, sha256_of, command, kind
):
    import masknet.io

    template, source = tmp_path / "template.xyz", tmp_path / "source.xyz"
    write_points(template, GOOD)
    write_points(source, GOOD[:200] + 0.01)
    target = source
    if kind == "symbolic link":
        target = tmp_path / "alias.xyz"
        target.symlink_to(source)
    elif kind == "hard link":
        target = tmp_path / "alias.xyz"
        target.hardlink_to(source)
    elif kind == "side file":  # the input is named as one of the side files of -o
        source = source.rename(tmp_path / f"out{SIDE_FILE[command]}")
        target = tmp_path / "out.xyz"
    before = sha256_of(tmp_path)

    def no_work(*args, **kwargs):
        raise AssertionError("an input was read: the refusal came after work started")

    monkeypatch.setattr(masknet.io, "read_points_with_rows", no_work)
    monkeypatch.setattr(masknet.io, "read_points", no_work)
    code = main([command, str(template), str(source), "-o", str(target)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "is the input" in err[0] and "never overwrites an input" in err[0]
    assert sha256_of(tmp_path) == before  # every input as it was, nothing new


def test_a_run_removes_the_side_files_of_an_earlier_run_that_it_did_not_write(tmp_path, capsys):
    template, source = tmp_path / "template.xyz", tmp_path / "source.xyz"
    write_points(template, GOOD)
    write_points(source, GOOD[GOOD[:, 0] > 0.3] + 0.01)
    out = tmp_path / "out.xyz"
    base = ["register", str(template), str(source), "-o", str(out)]
    assert main([*base, "--iterations", "2"]) == 0  # a loop masks the source
    side = tmp_path / "out_source_mask.txt"
    inliers = tmp_path / "out_inliers.xyz"
    assert side.exists() and inliers.exists()
    capsys.readouterr()
    assert main([*base, "--no-mask"]) == 0  # neither a source mask nor inliers now
    printed = capsys.readouterr().out
    assert not side.exists() and not inliers.exists()
    assert "removed" in printed and "out_source_mask.txt" in printed
    assert (tmp_path / "out_transform.txt").exists() and out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["template.xyz", "source.xyz", "out.xyz", "out_transform.txt"]
    )

"""Tests for masknet.io: round trips per format, one-line errors for bad input, atomic writes."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import masknet._open3d
from masknet.errors import MaskNetError, MaskNetWarning
from masknet.io import (
    SUPPORTED_READ,
    SUPPORTED_WRITE,
    PointsRead,
    read_points,
    read_points_with_rows,
    require_open3d,
    write_mask,
    write_points,
    write_text_atomic,
)


def _cloud(n: int = 100, seed: int = 0) -> np.ndarray:
    """(n, 3) float64 random points."""
    return np.random.default_rng(seed).normal(size=(n, 3))


def _raises(path: Path, *fragments: str, **kwargs) -> str:
    """read_points(path) raises a one-line MaskNetError naming the file; return the message."""
    with pytest.raises(MaskNetError) as info:
        read_points(path, **kwargs)
    msg = str(info.value)
    assert path.name in msg
    assert "\n" not in msg
    for fragment in fragments:
        assert fragment in msg, msg
    return msg


def _leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if ".tmp" in p.name)


# ------------------------------------------------------------------ round trips


@pytest.mark.parametrize("ext", [".ply", ".xyz", ".txt", ".npy"])
def test_round_trip_exact(tmp_path, ext):
    pts = _cloud()
    path = tmp_path / f"cloud{ext}"
    write_points(path, pts)
    got = read_points(path)
    assert got.dtype == np.float64 and got.shape == (100, 3)
    np.testing.assert_array_equal(got, pts)
    assert _leftovers(tmp_path) == []


def test_round_trip_pcd_is_float32(tmp_path):
    pts = _cloud()
    path = tmp_path / "cloud.pcd"
    write_points(path, pts)
    got = read_points(path)
    assert got.dtype == np.float64 and got.shape == (100, 3)
    np.testing.assert_allclose(got, pts, rtol=1e-6, atol=1e-6)
    assert _leftovers(tmp_path) == []


def test_upper_case_extension(tmp_path):
    pts = _cloud()
    for ext in (".PLY", ".PCD", ".NPY", ".XYZ"):
        path = tmp_path / f"cloud{ext}"
        write_points(path, pts)
        assert path.exists()
        np.testing.assert_allclose(read_points(path), pts, atol=1e-6)


def test_read_kitti_bin(tmp_path):
    scan = np.random.default_rng(1).normal(size=(50, 4)).astype(np.float32)
    path = tmp_path / "000000.bin"
    scan.tofile(path)
    got = read_points(path)
    assert got.dtype == np.float64
    np.testing.assert_array_equal(got, scan[:, :3].astype(np.float64))


def test_read_text_variants(tmp_path):
    pts = _cloud(5)
    extra = np.hstack([pts, np.ones((5, 3))]).tolist()  # e.g. normals
    csv = tmp_path / "cloud.csv"
    csv.write_text("x,y,z,nx,ny,nz\n" + "\n".join(",".join(map(repr, r)) for r in extra) + "\n")
    np.testing.assert_array_equal(read_points(csv), pts)
    txt = tmp_path / "cloud.txt"
    txt.write_text("# comment\n" + "\n".join("  ".join(map(repr, r)) for r in extra) + "\n")
    np.testing.assert_array_equal(read_points(txt), pts)


def test_read_npy_extra_columns_and_float32(tmp_path):
    arr = np.hstack([_cloud(10), np.zeros((10, 2))]).astype(np.float32)
    path = tmp_path / "cloud.npy"
    np.save(path, arr)
    got = read_points(path)
    assert got.dtype == np.float64 and got.shape == (10, 3)
    np.testing.assert_array_equal(got, arr[:, :3])


def test_read_ply_with_trimesh_when_open3d_missing(tmp_path, monkeypatch):
    pts = _cloud()
    path = tmp_path / "cloud.ply"
    write_points(path, pts)
    write_points(tmp_path / "cloud.pcd", pts)

    def broken():
        raise ImportError("libusb-1.0.so.0: cannot open shared object file")

    monkeypatch.setattr(masknet._open3d, "_load_open3d", broken)
    np.testing.assert_allclose(read_points(path), pts)
    _raises(tmp_path / "cloud.pcd", "needs Open3D", "libusb", "pip install open3d")


def test_require_open3d_message(monkeypatch):
    def broken():
        raise ImportError("No module named 'open3d'")

    monkeypatch.setattr(masknet._open3d, "_load_open3d", broken)
    with pytest.raises(MaskNetError) as info:
        require_open3d("Viewing clouds")
    msg = str(info.value)
    assert msg.startswith("Viewing clouds needs Open3D, which did not import (No module named")
    assert "`pip install open3d`" in msg and "`apt-get install libusb-1.0-0`" in msg


def test_require_open3d_returns_module(tmp_path):
    points = np.random.default_rng(0).random((20, 3))
    np.savetxt(tmp_path / "cloud.xyz", points)
    cloud = require_open3d("test").io.read_point_cloud(str(tmp_path / "cloud.xyz"))
    np.testing.assert_allclose(np.asarray(cloud.points), points, atol=1e-12)


# ------------------------------------------------------------------ bad input


def test_missing_file(tmp_path):
    _raises(tmp_path / "nope.ply", "no such file")


def test_directory(tmp_path):
    d = tmp_path / "dir.ply"
    d.mkdir()
    _raises(d, "directory")


def test_unknown_extension(tmp_path):
    path = tmp_path / "cloud.foo"
    path.write_text("1 2 3\n")
    msg = _raises(path, "unsupported extension '.foo'")
    for ext in SUPPORTED_READ:
        assert ext in msg


@pytest.mark.parametrize("ext", SUPPORTED_READ)
def test_empty_file(tmp_path, ext):
    path = tmp_path / f"empty{ext}"
    path.write_bytes(b"")
    _raises(path, "empty file")


@pytest.mark.parametrize("ext", [".ply", ".pcd"])
def test_truncated_open3d_file(tmp_path, ext, capfd):
    path = tmp_path / f"cut{ext}"
    write_points(path, _cloud(1000))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    _raises(path, "truncated or corrupt")
    out, err = capfd.readouterr()
    assert "Open3D" not in out + err and "RPly" not in out + err  # chatter kept quiet


@pytest.mark.parametrize("ext", [".pcd", ".ply"])
def test_garbage_bytes(tmp_path, ext):
    path = tmp_path / f"garbage{ext}"
    path.write_bytes(np.random.default_rng(0).bytes(500))
    _raises(path)


def test_garbage_text(tmp_path):
    path = tmp_path / "garbage.xyz"
    path.write_text("1 2 3\nhello world again\n4 5 6\n")
    _raises(path, "cannot parse")
    binary = tmp_path / "binary.xyz"
    binary.write_bytes(b"\xff\xfe\x00\x81" * 50)
    _raises(binary)


def test_truncated_npy_and_bin(tmp_path):
    npy = tmp_path / "cut.npy"
    np.save(npy, _cloud(100))
    npy.write_bytes(npy.read_bytes()[:300])
    _raises(npy, "not a valid")
    bin_ = tmp_path / "cut.bin"
    np.zeros((10, 4), np.float32).tofile(bin_)
    bin_.write_bytes(bin_.read_bytes()[:-3])
    _raises(bin_, "multiple of 16")


def test_npy_wrong_shapes(tmp_path):
    two = tmp_path / "two_cols.npy"
    np.save(two, np.zeros((10, 2)))
    _raises(two, "(10, 2)")
    flat = tmp_path / "flat.npy"
    np.save(flat, np.zeros(30))
    _raises(flat, "(30,)")
    obj = tmp_path / "strings.npy"
    np.save(obj, np.array([["a", "b", "c"]] * 4))
    _raises(obj, "dtype")


def test_too_few_points(tmp_path):
    path = tmp_path / "two.npy"
    np.save(path, _cloud(2))
    _raises(path, "only 2 point", "at least 3")


@pytest.mark.parametrize("ext", [".npy", ".ply", ".pcd", ".xyz"])
def test_nan_rows(tmp_path, ext):
    pts = _cloud(20)
    pts[3, 0] = np.nan
    pts[7, 2] = np.inf
    pts[8, 1] = -np.inf
    path = tmp_path / f"holes{ext}"
    write_points(path, pts)
    _raises(path, "3 rows contain NaN or inf", "--drop-nonfinite")
    got = read_points(path, drop_nonfinite=True)
    keep = np.isfinite(pts).all(axis=1)
    np.testing.assert_allclose(got, pts[keep], atol=1e-6)
    read = read_points_with_rows(path, drop_nonfinite=True)
    assert isinstance(read, PointsRead)
    np.testing.assert_array_equal(read.points, got)
    np.testing.assert_array_equal(read.rows, keep)


def test_return_rows_is_deprecated(tmp_path):
    path = tmp_path / "a.npy"
    np.save(path, _cloud(20))
    read = read_points_with_rows(path)
    assert read.rows.all() and read.rows.shape == (20,)
    with pytest.warns(DeprecationWarning, match="read_points_with_rows"):
        points, rows = read_points(path, return_rows=True)
    np.testing.assert_array_equal(points, read.points)
    np.testing.assert_array_equal(rows, read.rows)
    with pytest.warns(DeprecationWarning):
        np.testing.assert_array_equal(read_points(path, return_rows=False), read.points)


@pytest.mark.parametrize("ext", [".npy", ".ply"])
def test_all_nan(tmp_path, ext):
    path = tmp_path / f"allnan{ext}"
    write_points(path, np.full((5, 3), np.nan))
    _raises(path, "5 rows contain NaN or inf")
    _raises(path, "none remain", drop_nonfinite=True)


def test_drop_leaves_too_few(tmp_path):
    pts = _cloud(4)
    pts[:2] = np.nan
    path = tmp_path / "few.npy"
    np.save(path, pts)
    _raises(path, "only 2 point", drop_nonfinite=True)


# ------------------------------------------------------------------ writing


def test_write_unknown_extension_writes_nothing(tmp_path):
    path = tmp_path / "sub" / "cloud.foo"
    with pytest.raises(MaskNetError, match=r"cloud\.foo.*'\.foo'"):
        write_points(path, _cloud())
    assert not path.exists() and not path.parent.exists()
    with pytest.raises(MaskNetError, match=r"cloud\.bin"):  # readable but not writable
        write_points(tmp_path / "cloud.bin", _cloud())
    assert list(tmp_path.iterdir()) == []


def test_write_bad_shape(tmp_path):
    with pytest.raises(MaskNetError, match=r"bad\.npy.*\(10, 2\)"):
        write_points(tmp_path / "bad.npy", np.zeros((10, 2)))
    assert list(tmp_path.iterdir()) == []


def test_write_creates_parents_and_replaces(tmp_path):
    path = tmp_path / "a" / "b" / "cloud.ply"
    write_points(path, _cloud(10, seed=1))
    write_points(path, _cloud(20, seed=2))
    np.testing.assert_array_equal(read_points(path), _cloud(20, seed=2))
    assert _leftovers(path.parent) == []
    assert oct(path.stat().st_mode & 0o777) != oct(0o600)  # not mkstemp's private mode


def test_failed_write_leaves_nothing(tmp_path, monkeypatch):
    path = tmp_path / "cloud.npy"
    path_old = tmp_path / "old.npy"
    write_points(path_old, _cloud(5))

    def boom(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "save", boom)
    with pytest.raises(MaskNetError, match=r"cloud\.npy: cannot write \(No space left"):
        write_points(path, _cloud())
    with pytest.raises(MaskNetError, match="No space left"):
        write_points(path_old, _cloud())
    assert sorted(os.listdir(tmp_path)) == ["old.npy"]
    monkeypatch.undo()
    np.testing.assert_array_equal(read_points(path_old), _cloud(5))


def test_write_mask(tmp_path):
    path = tmp_path / "out" / "mask.txt"
    write_mask(path, np.array([True, False, True]))
    assert path.read_text() == "1\n0\n1\n"
    write_mask(path, np.array([0, 1, 1, 0]))
    assert path.read_text() == "0\n1\n1\n0\n"
    with pytest.raises(MaskNetError, match="mask.txt"):
        write_mask(path, np.array([0, 2]))
    with pytest.raises(MaskNetError, match=r"\(2, 2\)"):
        write_mask(path, np.zeros((2, 2)))
    assert path.read_text() == "0\n1\n1\n0\n"
    assert _leftovers(path.parent) == []


def test_write_text_atomic(tmp_path):
    path = tmp_path / "x" / "notes.json"
    write_text_atomic(path, '{"a": 1}\n')
    write_text_atomic(path, "héllo\n")
    assert path.read_text(encoding="utf-8") == "héllo\n"
    assert _leftovers(path.parent) == []


def test_supported_tuples():
    assert set(SUPPORTED_WRITE) <= set(SUPPORTED_READ)
    assert all(e.startswith(".") and e == e.lower() for e in SUPPORTED_READ)


def test_ply_header_that_disagrees_with_its_body_is_an_error(tmp_path):
    points = np.random.default_rng(0).random((50, 3))
    write_points(tmp_path / "a.ply", points)
    binary = (tmp_path / "a.ply").read_bytes()
    (tmp_path / "short.ply").write_bytes(binary.replace(b"element vertex 50", b"element vertex 10"))
    with pytest.raises(MaskNetError, match=r"short\.ply: the PLY header declares 10 vertices"):
        read_points(tmp_path / "short.ply")
    header = "ply\nformat ascii 1.0\nelement vertex 100\nproperty float x\nproperty float y\n"
    body = "\n".join(" ".join(f"{v:.4f}" for v in p) for p in points)
    text = header + "property float z\nend_header\n" + body + "\n"
    (tmp_path / "lying.ply").write_text(text)
    with pytest.raises(MaskNetError, match="declares 100 vertices but the body has 50 rows"):
        read_points(tmp_path / "lying.ply")
    (tmp_path / "true.ply").write_text(text.replace("vertex 100", "vertex 50"))
    assert read_points(tmp_path / "true.ply").shape == (50, 3)


def test_degenerate_and_absurd_clouds_are_named(tmp_path, capsys):
    cases = {
        "same.npy": (np.ones((20, 3)), "all 20 points are identical"),
        "line.npy": (np.outer(np.arange(20.0), [1, 2, 3]), "lie on one line"),
        "huge.npy": (
            np.full((20, 3), 1e39) * np.random.default_rng(0).random((20, 3)),
            "beyond float32",
        ),
    }
    for name, (points, message) in cases.items():
        np.save(tmp_path / name, points)
        with pytest.raises(MaskNetError, match=message) as info:
            read_points(tmp_path / name)
        assert name in str(info.value)
    few = np.random.default_rng(1).random((5, 3))
    np.save(tmp_path / "few.npy", few)
    with pytest.warns(MaskNetWarning, match="few.npy: only 5 points; the result is unreliable"):
        assert read_points(tmp_path / "few.npy").shape == (5, 3)
    far = np.concatenate([np.random.default_rng(2).random((200, 3)), [[1e6, 0, 0]]])
    np.save(tmp_path / "far.npy", far)
    with pytest.warns(MaskNetWarning, match="far.npy: one point lies"):
        read_points(tmp_path / "far.npy")


def test_pcd_header_that_disagrees_with_its_body_is_an_error(tmp_path, o3d):
    write_points(tmp_path / "a.pcd", np.random.default_rng(0).random((50, 3)))
    raw = (tmp_path / "a.pcd").read_bytes()
    assert read_points(tmp_path / "a.pcd").shape == (50, 3)
    lying = raw.replace(b"WIDTH 50", b"WIDTH 500").replace(b"POINTS 50", b"POINTS 500")
    (tmp_path / "more.pcd").write_bytes(lying)
    with pytest.raises(
        MaskNetError,
        match=r"more\.pcd: truncated or corrupt .pcd file \(the header declares 500 points",
    ):
        read_points(tmp_path / "more.pcd")
    (tmp_path / "wh.pcd").write_bytes(raw.replace(b"POINTS 50", b"POINTS 40"))
    with pytest.raises(MaskNetError, match="declares 40 points but WIDTH x HEIGHT is 50 x 1"):
        read_points(tmp_path / "wh.pcd")
    header = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
    text = header + "WIDTH 5\nHEIGHT 1\nPOINTS 5\nDATA ascii\n" + "0 0 0\n1 0 0\n0 1 0\n"
    (tmp_path / "rows.pcd").write_text(text)
    with pytest.raises(MaskNetError, match="declares 5 points but the body has 3 rows"):
        read_points(tmp_path / "rows.pcd")


def test_ctrl_c_while_open3d_imports_is_an_interrupt_not_a_missing_package(monkeypatch, o3d):
    """Ctrl-C during Open3D's C initialisation used to surface as 'needs Open3D, which did
    not import (initialization failed)'. The interrupt is held until the import ends."""
    import builtins
    import signal

    from masknet import io as masknet_io

    real_import = builtins.__import__

    def import_with_ctrl_c(name, *args, **kwargs):
        if name == "open3d":
            try:
                signal.raise_signal(signal.SIGINT)  # arrives in the middle of the import
            except KeyboardInterrupt:  # as Open3D's C initialisation reports it
                raise ImportError("initialization failed") from None
        return real_import(name, *args, **kwargs)

    masknet._open3d._load_open3d.cache_clear()
    # Python's own handler, as in a terminal: a process started in the background by a
    # shell inherits SIGINT ignored, and then Ctrl-C is nothing to hold
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    monkeypatch.setattr(builtins, "__import__", import_with_ctrl_c)
    before = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt):
        masknet_io.require_open3d("reading .pcd files")
    assert signal.getsignal(signal.SIGINT) is before  # the user's handler is back
    signal.signal(signal.SIGINT, previous)
    monkeypatch.setattr(builtins, "__import__", real_import)
    masknet._open3d._load_open3d.cache_clear()
    assert masknet_io.require_open3d("reading .pcd files") is o3d

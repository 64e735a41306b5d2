"""Tests for masknet.data.modelnet: every layout on tiny synthetic datasets in tmp_path."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from masknet.data.modelnet import PointCloudSet, load_modelnet40, normalize_unit_sphere
from masknet.errors import MaskNetError

CLASSES = ["airplane", "bathtub", "bed"]


def _assert_unit_normalised(points: np.ndarray) -> None:
    """Bounding-box centre at the origin and largest radius 1, per shape."""
    centre = (points.max(1) + points.min(1)) / 2
    np.testing.assert_allclose(centre, 0, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(points, axis=-1).max(1), 1.0, rtol=1e-6)


def _random_shapes(rng: np.random.Generator, s: int, n: int) -> np.ndarray:
    # Off-centre, oddly scaled shapes so normalisation has work to do.
    return (rng.normal(size=(s, n, 3)) * 3 + rng.uniform(-5, 5, size=(s, 1, 3))).astype(np.float32)


def _write_hdf5(folder: Path, rng: np.random.Generator) -> dict:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "shape_names.txt").write_text("\n".join(CLASSES) + "\n")
    out = {}
    for split, s in (("train", 4), ("test", 3)):
        data = _random_shapes(rng, s, 2048)
        # Make the second half far away: if it were used, normalisation would differ.
        data[:, 1024:] += 1000.0
        labels = rng.integers(0, len(CLASSES), size=(s, 1)).astype(np.uint8)
        with h5py.File(folder / f"ply_data_{split}0.h5", "w") as h5:
            h5.create_dataset("data", data=data)
            h5.create_dataset("label", data=labels)
        out[split] = (data, labels[:, 0])
    return out


@pytest.mark.parametrize("split", ["train", "test"])
def test_hdf5_layout(tmp_path, split):
    folder = tmp_path / "modelnet40_ply_hdf5_2048"
    written = _write_hdf5(folder, np.random.default_rng(0))
    data, labels = written[split]
    for path in (folder, tmp_path, str(folder)):
        ds = load_modelnet40(path, split=split)
        assert isinstance(ds, PointCloudSet)
        assert ds.points.shape == (len(data), 1024, 3) and ds.points.dtype == np.float32
        assert ds.labels.dtype == np.int64
        np.testing.assert_array_equal(ds.labels, labels)
        assert ds.shape_names == CLASSES
        assert len(ds) == len(data) and len(ds.names) == len(data)
        assert [n.rsplit("_", 1)[0] for n in ds.names] == [CLASSES[c] for c in labels]
        assert len(set(ds.names)) == len(ds.names)
        _assert_unit_normalised(ds.points)
        # Exactly the first 1024 stored points, normalised.
        np.testing.assert_allclose(ds.points, normalize_unit_sphere(data[:, :1024]), atol=1e-6)


def test_hdf5_multiple_shards_concatenated(tmp_path):
    rng = np.random.default_rng(1)
    written = _write_hdf5(tmp_path, rng)
    extra = _random_shapes(rng, 2, 2048)
    with h5py.File(tmp_path / "ply_data_test1.h5", "w") as h5:
        h5.create_dataset("data", data=extra)
        h5.create_dataset("label", data=np.array([[2], [0]], np.uint8))
    ds = load_modelnet40(tmp_path, split="test")
    assert ds.points.shape == (5, 1024, 3)
    np.testing.assert_array_equal(ds.labels, [*written["test"][1], 2, 0])


def test_hdf5_num_points(tmp_path):
    _write_hdf5(tmp_path, np.random.default_rng(2))
    assert load_modelnet40(tmp_path, split="test", num_points=512).points.shape == (3, 512, 3)


def test_hdf5_missing_shape_names_raises(tmp_path):
    _write_hdf5(tmp_path, np.random.default_rng(3))
    (tmp_path / "shape_names.txt").unlink()
    with pytest.raises(MaskNetError, match="shape_names.txt"):
        load_modelnet40(tmp_path)


def _write_npy(root: Path, rng: np.random.Generator, n: int = 1100) -> dict:
    files = {}
    for label, cls in enumerate(CLASSES[:2]):
        for split, count in (("train", 2), ("test", 1 + label)):
            d = root / cls / split
            d.mkdir(parents=True)
            for i in range(count):
                name = f"{cls}_{split}_{i:04d}"
                cloud = _random_shapes(rng, 1, n)[0]
                np.save(d / f"{name}.npy", cloud)
                files.setdefault(split, []).append((name, label, cloud))
    return files


def test_npy_layout(tmp_path):
    files = _write_npy(tmp_path, np.random.default_rng(4))
    for split in ("train", "test"):
        ds = load_modelnet40(tmp_path, split=split)
        expected = files[split]
        assert ds.points.shape == (len(expected), 1024, 3) and ds.points.dtype == np.float32
        assert ds.shape_names == CLASSES[:2]
        assert list(ds.names) == [name for name, _, _ in expected]
        np.testing.assert_array_equal(ds.labels, [label for _, label, _ in expected])
        _assert_unit_normalised(ds.points)
        clouds = np.stack([c[:1024] for _, _, c in expected])
        np.testing.assert_allclose(ds.points, normalize_unit_sphere(clouds), atol=1e-6)


def test_npy_too_few_points_raises(tmp_path):
    _write_npy(tmp_path, np.random.default_rng(5), n=100)
    with pytest.raises(MaskNetError, match="100 points"):
        load_modelnet40(tmp_path)


def _write_npz(path: Path, rng: np.random.Generator, keys: set | None = None) -> dict:
    shape_names = np.array([f"class{i:02d}" for i in range(40)])
    arrays = {"scale": np.float32(1 / 1000), "shape_names": shape_names}
    for split, s in (("train", 5), ("test", 4)):
        pts = rng.integers(-30000, 30000, size=(s, 1024, 3)).astype(np.int16)
        arrays[f"{split}_points"] = pts
        arrays[f"{split}_labels"] = rng.integers(0, 40, size=s).astype(np.int16)
        arrays[f"{split}_names"] = np.array([f"shape_{split}_{i}" for i in range(s)])
    if keys is not None:
        arrays = {k: v for k, v in arrays.items() if k in keys}
    np.savez(path, **arrays)
    return arrays


def test_npz_layout(tmp_path):
    path = tmp_path / "modelnet40_1024_int16.npz"
    arrays = _write_npz(path, np.random.default_rng(6))
    for source in (path, tmp_path):  # the file, or a folder holding exactly one .npz
        ds = load_modelnet40(source, split="train")
        assert ds.points.shape == (5, 1024, 3) and ds.points.dtype == np.float32
        np.testing.assert_array_equal(ds.labels, arrays["train_labels"])
        assert ds.labels.dtype == np.int64
        assert list(ds.names) == list(arrays["train_names"])
        assert ds.shape_names == [f"class{i:02d}" for i in range(40)]
        _assert_unit_normalised(ds.points)
        expected = normalize_unit_sphere(arrays["train_points"].astype(np.float32) / 1000)
        np.testing.assert_allclose(ds.points, expected, atol=1e-6)
    assert load_modelnet40(path, split="test").points.shape == (4, 1024, 3)


def test_npz_without_optional_keys(tmp_path):
    path = tmp_path / "small.npz"
    _write_npz(path, np.random.default_rng(7), keys={"test_points", "test_labels", "shape_names"})
    ds = load_modelnet40(path, split="test")
    assert ds.points.shape == (4, 1024, 3)
    assert len(ds.names) == 4


def test_npz_missing_keys_raises(tmp_path):
    path = tmp_path / "broken.npz"
    _write_npz(path, np.random.default_rng(8), keys={"train_points", "train_labels", "shape_names"})
    with pytest.raises(MaskNetError, match="broken.npz") as info:
        load_modelnet40(path, split="test")
    assert "test_points" in str(info.value)


CUBE_OFF = """OFF
8 12 0
-1 -1 -1
1 -1 -1
1 1 -1
-1 1 -1
-1 -1 1
1 -1 1
1 1 1
-1 1 1
3 0 2 1
3 0 3 2
3 4 5 6
3 4 6 7
3 0 1 5
3 0 5 4
3 2 3 7
3 2 7 6
3 1 2 6
3 1 6 5
3 0 4 7
3 0 7 3
"""


def _write_off(root: Path) -> None:
    for cls, shift in (("box", 0.0), ("crate", 5.0)):
        for split in ("train", "test"):
            d = root / cls / split
            d.mkdir(parents=True)
            lines = CUBE_OFF.splitlines()
            moved = [
                " ".join(str(float(v) * 2 + shift) for v in line.split())
                if i in range(2, 10)
                else line
                for i, line in enumerate(lines)
            ]
            (d / f"{cls}_0001.off").write_text("\n".join(moved) + "\n")


def test_off_layout_samples_cube_surface(tmp_path):
    _write_off(tmp_path)
    ds = load_modelnet40(tmp_path, split="test")
    assert ds.points.shape == (2, 1024, 3) and ds.points.dtype == np.float32
    assert ds.shape_names == ["box", "crate"]
    np.testing.assert_array_equal(ds.labels, [0, 1])
    assert list(ds.names) == ["box_0001", "crate_0001"]
    _assert_unit_normalised(ds.points)
    for cloud in ds.points:
        lo, hi = cloud.min(0), cloud.max(0)
        # A cube stays a cube: equal extents, a little over 2 / sqrt(3) since the
        # farthest sample is near, not at, a corner.
        extent = hi - lo
        np.testing.assert_allclose(extent, extent[0], atol=1e-5)
        assert 2 / np.sqrt(3) - 1e-5 <= extent[0] < 1.25
        # Every point lies on a face: some coordinate equals the box bound.
        on_face = (np.abs(cloud - lo) < 1e-5) | (np.abs(cloud - hi) < 1e-5)
        assert on_face.any(axis=1).all()
        # And the samples are spread over all six faces.
        on_low, on_high = np.abs(cloud - lo) < 1e-5, np.abs(cloud - hi) < 1e-5
        assert min(on_low.sum(0).min(), on_high.sum(0).min()) > 50
    # Sampling is reproducible.
    again = load_modelnet40(tmp_path, split="test")
    np.testing.assert_array_equal(again.points, ds.points)


def test_class_folders_without_shapes_raise(tmp_path):
    (tmp_path / "chair" / "test").mkdir(parents=True)
    (tmp_path / "chair" / "test" / "readme.txt").write_text("nothing here")
    with pytest.raises(MaskNetError, match="download"):
        load_modelnet40(tmp_path, split="test")


def test_missing_path_raises(tmp_path):
    missing = tmp_path / "nowhere"
    with pytest.raises(MaskNetError, match="nowhere") as info:
        load_modelnet40(missing)
    assert "download" in str(info.value)


def test_empty_folder_raises(tmp_path):
    with pytest.raises(MaskNetError) as info:
        load_modelnet40(tmp_path)
    assert str(tmp_path) in str(info.value)
    assert "download" in str(info.value)


def test_text_file_raises(tmp_path):
    path = tmp_path / "points.txt"
    path.write_text("1 2 3\n")
    with pytest.raises(MaskNetError, match="points.txt") as info:
        load_modelnet40(path)
    assert "download" in str(info.value)


def test_no_path_and_no_env_raises(monkeypatch):
    monkeypatch.delenv("MASKNET_DATA", raising=False)
    with pytest.raises(MaskNetError, match="download"):
        load_modelnet40()


def test_env_variable_is_used(tmp_path, monkeypatch):
    path = tmp_path / "data.npz"
    _write_npz(path, np.random.default_rng(9))
    monkeypatch.setenv("MASKNET_DATA", str(path))
    assert load_modelnet40(split="test").points.shape == (4, 1024, 3)


def test_bad_split_raises(tmp_path):
    with pytest.raises(MaskNetError, match="split"):
        load_modelnet40(tmp_path, split="val")


def test_subset_seen_unseen():
    labels = np.array([0, 5, 19, 20, 33, 39, 1])
    ds = PointCloudSet(
        points=np.zeros((7, 4, 3), np.float32),
        labels=labels,
        names=np.array([f"s{i}" for i in range(7)]),
        shape_names=[f"c{i}" for i in range(40)],
    )
    seen, unseen = ds.subset("seen"), ds.subset("unseen")
    np.testing.assert_array_equal(seen.labels, [0, 5, 19, 1])
    np.testing.assert_array_equal(unseen.labels, [20, 33, 39])
    assert list(seen.names) == ["s0", "s1", "s2", "s6"]
    assert list(unseen.names) == ["s3", "s4", "s5"]
    assert seen.points.shape == (4, 4, 3) and unseen.shape_names == ds.shape_names
    assert ds.subset("all") is ds
    with pytest.raises(MaskNetError):
        ds.subset("half")


def test_corrupt_npz_is_one_clear_error(tmp_path):
    from masknet.data import bundled_sample_path

    truncated = tmp_path / "cut.npz"
    truncated.write_bytes(bundled_sample_path().read_bytes()[:5000])
    garbage = tmp_path / "junk.npz"
    garbage.write_bytes(b"\x00" * 100)
    for path in (truncated, garbage):
        with pytest.raises(MaskNetError, match=path.name):
            load_modelnet40(path, "test")


def test_npz_with_nan_shapes_is_refused(tmp_path):
    points = np.zeros((2, 1024, 3), np.float32)
    points[1, 5] = np.nan
    path = tmp_path / "nan.npz"
    np.savez(
        path, test_points=points, test_labels=np.array([0, 1]), shape_names=np.array(["a", "b"])
    )
    with pytest.raises(MaskNetError, match="1 shapes contain NaN"):
        load_modelnet40(path, "test")

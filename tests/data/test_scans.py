"""Real scans as data: reading a folder, whole-scan validation splits, seeded crops."""

from __future__ import annotations

import numpy as np
import pytest

from masknet.data.scans import (
    ScanCropConfig,
    default_validation_scans,
    iterate_scan_pairs,
    load_scans,
    make_scan_test_pairs,
    split_scans,
)
from masknet.data.views import ViewConfig
from masknet.errors import MaskNetError

VIEW = ViewConfig(template_points=128)
CROP = ScanCropConfig(crop_points=(300, 600))


def _plane_scan(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-2, 2, (n, 2))
    z = 0.3 * np.sin(xy[:, 0] * 2) * np.cos(xy[:, 1])
    return np.column_stack([xy, z]).astype(np.float32)


@pytest.fixture
def scan_folder(tmp_path):
    for i in range(3):
        np.save(tmp_path / f"scan{i}.npy", _plane_scan(3000, i))
    return tmp_path


def test_load_scans_reads_every_file_and_skips_bad_ones_with_one_line(scan_folder, capsys):
    (scan_folder / "broken.ply").write_text("ply\nformat nonsense\n")
    np.save(scan_folder / "tiny.npy", _plane_scan(50, 9))
    (scan_folder / "notes.md").write_text("not a scan")
    scans = load_scans(scan_folder)
    assert [s.name for s in scans] == ["scan0", "scan1", "scan2"]
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2
    assert any("broken.ply" in line and "skipped" in line for line in err)
    assert any("tiny.npy: only 50 points" in line for line in err)


def test_load_scans_refuses_a_missing_or_empty_folder(tmp_path):
    with pytest.raises(MaskNetError, match="no such folder"):
        load_scans(tmp_path / "absent")
    with pytest.raises(MaskNetError, match="no usable scan"):
        load_scans(tmp_path)


def test_load_scans_keeps_a_fixed_subset_of_large_scans(scan_folder):
    a = load_scans(scan_folder, max_points=1500)
    b = load_scans(scan_folder, max_points=1500)
    assert len(a[0]) == 1500
    assert np.array_equal(a[0].points, b[0].points)


def test_whole_scans_are_held_out_by_name(scan_folder):
    scans = load_scans(scan_folder)
    assert default_validation_scans([f"s{i:02d}" for i in range(11)]) == ["s02", "s07"]
    train, val = split_scans(scans, ["scan1"])
    assert [s.name for s in train] == ["scan0", "scan2"] and [s.name for s in val] == ["scan1"]
    with pytest.raises(MaskNetError, match="validation scans not found: nope"):
        split_scans(scans, ["nope"])
    with pytest.raises(MaskNetError, match="none is left"):
        split_scans(scans, ["scan0", "scan1", "scan2"])


def test_scan_pairs_are_seeded_and_test_pairs_name_their_scan(scan_folder):
    scans = load_scans(scan_folder)
    first = list(iterate_scan_pairs(scans, VIEW, CROP, 2, 4, seed=1, epoch=0))
    again = list(iterate_scan_pairs(scans, VIEW, CROP, 2, 4, seed=1, epoch=0))
    other = list(iterate_scan_pairs(scans, VIEW, CROP, 2, 4, seed=1, epoch=1))
    assert len(first) == 2 and first[0].template.shape == (4, 128, 3)
    assert np.array_equal(first[1].source, again[1].source)
    assert not np.array_equal(first[1].source, other[1].source)
    pairs, names = make_scan_test_pairs(scans, 3, VIEW, CROP, seed=0)
    assert names == ["scan0"] * 3 + ["scan1"] * 3 + ["scan2"] * 3
    assert pairs.source.shape == (9, 90, 3)
    # Crops are unit-radius clouds, so templates are too.
    radius = pairs.template.norm(dim=-1).amax(1)
    assert float(radius.max()) <= 1.0 + 1e-5 and float(radius.min()) > 0.5

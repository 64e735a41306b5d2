"""masknet register-many: a result per pair, a summary, failures recorded, resumable."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from masknet.cli import main
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.registration.judge.assessment import VERDICTS


@pytest.fixture()
def batch(tmp_path):
    shapes = load_modelnet40(bundled_sample_path(), "test").points[:3]
    made = make_test_pairs(shapes, 3, PairConfig(), seed=9)
    lines = []
    for i in range(3):
        np.save(tmp_path / f"t{i}.npy", made.template[i].numpy())
        np.save(tmp_path / f"s{i}.npy", made.source[i].numpy())
        lines.append(f"t{i}.npy s{i}.npy")
    lines.append("t0.npy nowhere.npy broken  # a pair that cannot be read")
    (tmp_path / "pairs.txt").write_text("\n".join(lines) + "\n")
    return tmp_path


def _summary(out) -> list[dict]:
    with open(out / "summary.csv") as f:
        return list(csv.DictReader(f))


def test_a_batch_records_every_pair_and_a_failure_without_stopping(batch, capsys):
    out = batch / "out"
    args = ["register-many", "--list", str(batch / "pairs.txt"), "-o", str(out), "--workers", "2"]
    assert main([*args, "--method", "icp"]) == 4  # one pair failed, the rest are written
    rows = _summary(out)
    assert [r["name"] for r in rows] == ["s0", "s1", "s2", "broken"]
    assert [r["status"] for r in rows] == ["registered"] * 3 + ["failed"]
    assert "nowhere.npy" in rows[3]["error"]
    transform = np.loadtxt(out / "s1_transform.txt")
    assert transform.shape == (4, 4)
    assert json.loads((out / "s1.json").read_text())["verdict"] in VERDICTS
    err = capsys.readouterr().err
    assert "[4/4]" in err and "4 to register" in err
    assert main([*args, "--method", "icp", "--exit-zero"]) == 0


def test_a_rerun_registers_only_the_pairs_not_finished(batch, capsys):
    out = batch / "out"
    args = ["register-many", "--list", str(batch / "pairs.txt"), "-o", str(out), "--workers", "1"]
    main([*args, "--method", "icp"])
    before = (out / "s0.json").read_text()
    (out / "s2.json").unlink()  # as if the run had been stopped before s2 finished
    capsys.readouterr()
    main([*args, "--method", "icp"])
    err = capsys.readouterr().err
    # s2 again, and the pair that failed (it is tried again); s0 and s1 are kept
    assert "2 finished earlier, 2 to register" in err and "s2:" in err
    assert (out / "s0.json").read_text() == before  # untouched
    assert len(_summary(out)) == 4
    # Other options are another batch: every pair again, and the summary is only theirs.
    main([*args, "--method", "icp", "--iterations", "2"])
    assert "0 finished earlier, 4 to register" in capsys.readouterr().err


def test_options_no_pair_could_take_are_refused_before_any_work(batch, capsys):
    out = batch / "refused"
    args = ["register-many", "--list", str(batch / "pairs.txt"), "-o", str(out)]
    assert main([*args, "--method", "pointnetlk", "--max-correspondence-distance", "0.1"]) == 2
    assert "max_correspondence_distance" in capsys.readouterr().err
    (batch / "bad_start.txt").write_text("2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    assert main([*args, "--method", "icp", "--init", str(batch / "bad_start.txt")]) == 2
    assert "rigid" in capsys.readouterr().err
    assert not out.exists() or not list(out.iterdir())
    (batch / "names.txt").write_text("t0.npy s0.npy ../escape\n")
    assert main(["register-many", "--list", str(batch / "names.txt"), "-o", str(out)]) == 2
    assert "without folders" in capsys.readouterr().err


def test_one_template_against_a_glob_of_sources(batch, capsys):
    out = batch / "glob"
    args = [
        "register-many",
        "--template",
        str(batch / "t0.npy"),
        "--sources",
        str(batch / "s*.npy"),
    ]
    assert main([*args, "-o", str(out), "--workers", "1", "--exit-zero"]) == 0
    assert [r["name"] for r in _summary(out)] == ["s0", "s1", "s2"]
    assert main(["register-many", "--template", str(batch / "t0.npy"), "-o", str(out)]) == 2
    assert "--sources" in capsys.readouterr().err

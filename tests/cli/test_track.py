"""``masknet track``: poses.csv and trajectory.png, an interrupted run, --resume, the
frames' order."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from masknet.cli import main
from masknet.cli.track import COLUMNS, frame_paths
from masknet.data import bundled_sample_path, load_modelnet40
from masknet.geometry.se3 import rotation_angle_deg
from masknet.tracking.sequences import SequenceConfig, make_sequence

pytestmark = pytest.mark.filterwarnings("ignore::masknet.errors.MaskNetWarning")


@pytest.fixture(scope="module")
def frame_files(tmp_path_factory):
    """Four frames of a chair as frame_<k>.npy, its template and the first frame's pose."""
    folder = tmp_path_factory.mktemp("frames")
    shapes = load_modelnet40(bundled_sample_path(), "test").points
    config = SequenceConfig(frames=4, occlusion_frames=0, jump_deg=0, jump_shift=0, clutter=1)
    seq = make_sequence(shapes[24], [shapes[40]], config, seed=1)
    np.savetxt(folder / "chair.xyz", seq.template)
    for k, frame in enumerate(seq.frames):
        np.save(folder / f"frame_{k}.npy", frame)
    np.savetxt(folder / "start.txt", seq.truth[0])
    return folder, seq


def _rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def _command(folder, out, *more):
    glob = str(folder / "frame_*.npy")
    return ["track", str(folder / "chair.xyz"), glob, "-o", str(out), *more]


def test_track_writes_poses_and_a_trajectory(frame_files, tmp_path, capsys):
    folder, seq = frame_files
    init = ["--init", str(folder / "start.txt")]
    assert main(_command(folder, tmp_path / "out", *init, "--every", "2")) == 0
    rows = _rows(tmp_path / "out" / "poses.csv")
    assert list(rows[0]) == COLUMNS and [r["frame"] for r in rows] == ["0", "1", "2", "3"]
    assert {r["state"] for r in rows} == {"tracked"}
    for k, row in enumerate(rows):
        transform = np.array([float(row[f"t{i}{j}"]) for i in range(4) for j in range(4)])
        delta = transform.reshape(4, 4) @ np.linalg.inv(seq.truth[k])  # the identity if right
        centre = np.append(seq.template.mean(0), 1)
        assert (
            rotation_angle_deg(delta[:3, :3]) < 2 and np.linalg.norm(delta @ centre - centre) < 0.02
        )
    png = (tmp_path / "out" / "trajectory.png").read_bytes()
    assert png.startswith(b"\x89PNG") and len(png) > 20_000
    err = capsys.readouterr().err
    assert "masknet: track: 4/4" in err and "tracked (likely correct)" in err


def test_an_interrupted_run_keeps_the_frames_done_and_resumes(frame_files, tmp_path, monkeypatch):
    from masknet.tracking.tracker import Tracker

    folder, _ = frame_files
    out = tmp_path / "out"
    update, calls = Tracker.update, []

    def interrupted(self, frame, name=None):
        if len(calls) == 2:
            raise KeyboardInterrupt  # Ctrl-C during the third frame
        calls.append(name)
        return update(self, frame, name)

    monkeypatch.setattr(Tracker, "update", interrupted)
    init = ["--init", str(folder / "start.txt")]
    assert main(_command(folder, out, *init)) == 130
    rows = _rows(out / "poses.csv")
    assert [r["frame"] for r in rows] == ["0", "1"] and rows[1]["state"] == "tracked"
    assert sorted(p.name for p in out.iterdir()) == ["poses.csv"]  # no temporary file left
    monkeypatch.setattr(Tracker, "update", update)
    assert main(_command(folder, out, "--resume")) == 0
    rows = _rows(out / "poses.csv")
    assert [r["frame"] for r in rows] == ["0", "1", "2", "3"]
    assert {r["state"] for r in rows} == {"tracked"}  # from the last pose, not searched


def test_frames_in_natural_order_from_a_glob_or_a_list(tmp_path):
    for k in (10, 2, 1):
        (tmp_path / f"f_{k}.npy").touch()
    (tmp_path / "frames.txt").write_text("f_10.npy\n# a comment\nf_1.npy\n")
    glob = frame_paths([str(tmp_path / "f_*.npy")])
    assert [p.rsplit("/", 1)[1] for p in glob] == ["f_1.npy", "f_2.npy", "f_10.npy"]
    listed = frame_paths([f"@{tmp_path / 'frames.txt'}"])
    assert listed == [str(tmp_path / "f_10.npy"), str(tmp_path / "f_1.npy")]


def test_a_frame_in_another_unit_is_refused_in_one_line(frame_files, tmp_path, capsys):
    folder, seq = frame_files
    scaled = tmp_path / "frame_mm.npy"
    np.save(scaled, seq.frames[1] * 1000)
    args = ["track", str(folder / "chair.xyz"), str(folder / "frame_0.npy"), str(scaled)]
    args += ["-o", str(tmp_path / "out"), "--init", str(folder / "start.txt")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"masknet: error: {scaled}: the clouds look like different units")
    assert len(_rows(tmp_path / "out" / "poses.csv")) == 1  # the frame before it

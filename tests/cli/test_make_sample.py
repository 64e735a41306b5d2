"""masknet make-sample: a small sample of ModelNet40's test split, per category."""

from __future__ import annotations

import numpy as np

from masknet.cli import main
from masknet.data import bundled_sample_path, load_modelnet40


def test_a_sample_of_the_sample_keeps_every_category(tmp_path, capsys):
    out = tmp_path / "sample.npz"
    assert (
        main(
            [
                "make-sample",
                "--data",
                str(bundled_sample_path()),
                "-o",
                str(out),
                "--per-class",
                "1",
            ]
        )
        == 0
    )
    made, source = load_modelnet40(out, "test"), load_modelnet40(bundled_sample_path(), "test")
    assert len(made.points) == len(set(source.labels.tolist())) == len(set(made.labels.tolist()))
    assert made.points.shape[1:] == source.points.shape[1:]
    assert np.isin(
        made.points.reshape(len(made.points), -1)[:, :6].tolist(),
        source.points.reshape(len(source.points), -1)[:, :6].tolist(),
    ).all()


def test_a_missing_data_file_is_one_line(tmp_path, capsys):
    assert (
        main(["make-sample", "--data", str(tmp_path / "none.npz"), "-o", str(tmp_path / "s.npz")])
        == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "none.npz" in err[0]
    assert not (tmp_path / "s.npz").exists()

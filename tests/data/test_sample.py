"""masknet.data.sample and ``masknet make-sample``: the bundled sample is rebuilt
exactly from the ModelNet40 test split, by name within each category."""

from __future__ import annotations

import os

import numpy as np

from masknet.cli import main
from masknet.data import bundled_sample_path
from masknet.data.modelnet import normalize_unit_sphere


def _arrays(path) -> dict[str, np.ndarray]:
    with np.load(path) as data:
        return {key: data[key] for key in data.files}


def test_picks_the_first_shapes_by_name_in_every_category(tmp_path, capsys):
    """A made-up test split: 2 categories, names out of order; per class 2."""
    rng = np.random.default_rng(0)
    names = np.array(["b_3", "a_2", "a_1", "b_1", "a_3", "b_2"])
    labels = np.array([1, 0, 0, 1, 0, 1])
    points = normalize_unit_sphere(rng.uniform(-2, 3, size=(6, 1024, 3)))  # as loaded
    np.savez(
        tmp_path / "split.npz",
        train_points=points,
        train_labels=labels,
        train_names=names,
        test_points=points,
        test_labels=labels,
        test_names=names,
        shape_names=np.array(["a", "b"]),
    )
    out = tmp_path / "sample.npz"
    code = main(
        ["make-sample", "--data", str(tmp_path / "split.npz"), "-o", str(out), "--per-class", "2"]
    )
    assert code == 0 and "wrote" in capsys.readouterr().out
    sample = _arrays(out)
    assert list(sample["test_names"]) == ["a_1", "a_2", "b_1", "b_2"]
    assert list(sample["test_labels"]) == [0, 0, 1, 1]
    order = [2, 1, 3, 5]
    restored = sample["test_points"].astype(np.float32) * sample["scale"]
    np.testing.assert_allclose(restored, points[order], atol=1 / 32767)
    assert not list(tmp_path.glob("*.tmp*"))


def test_rebuilds_the_bundled_sample_exactly(tmp_path, skip_unless_ci):
    data = os.environ.get("MASKNET_DATA")
    if not data or not os.path.exists(data):
        skip_unless_ci("MASKNET_DATA (the full ModelNet40 .npz) is not set")
    out = tmp_path / "sample.npz"
    assert main(["make-sample", "--data", data, "-o", str(out)]) == 0
    built, shipped = _arrays(out), _arrays(bundled_sample_path())
    assert built.keys() == shipped.keys()
    for key in shipped:
        np.testing.assert_array_equal(built[key], shipped[key])

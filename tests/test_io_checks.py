"""masknet.io_checks.check_cloud: one set of checks for the command line and the API.

Every case runs through ``masknet register`` (the cloud saved as the source ``.npy``)
and through ``register()`` (the array itself), and must get the same verdict: refused
with the same problem (exit 2 and one line, nothing written, inputs unchanged; a
MaskNetError, word for word but for a hint that names the command line's option or
Python's), or accepted with the same warning (one ``masknet: warning:`` line; a
MaskNetWarning).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from masknet import register
from masknet.cli import main
from masknet.errors import MaskNetError, MaskNetWarning
from masknet.io_checks import ARRAY_NONFINITE_HINT, FILE_NONFINITE_HINT, check_cloud

RNG = np.random.default_rng(0)
TEMPLATE = RNG.random((300, 3))
SOURCE = TEMPLATE[:200] + [0.01, 0.0, 0.0]


def _nan_rows() -> np.ndarray:
    cloud = SOURCE.copy()
    cloud[[3, 50, 99]] = np.nan
    return cloud


def _far_point() -> np.ndarray:
    return np.concatenate([SOURCE, [[1e6, 0.0, 0.0]]])


# name -> (the source cloud, "refused" or "warned", the problem both must name)
CASES = {
    "transposed": (SOURCE.T.copy(), "refused", "looks transposed (3 rows of coordinates)"),
    "three collinear": (np.array([[0.0, 0, 0], [1, 1, 1], [2, 2, 2]]), "refused", "lie on one line"),
    "identical": (np.ones((500, 3)), "refused", "all 500 points are identical"),
    "overflow": (SOURCE * 1e37, "refused", "squared distances would overflow float32"),
    "one point at 1e38": (np.concatenate([SOURCE, [[1e38, 0, 0]]]), "refused", "would overflow"),
    "beyond float32": (SOURCE * 1e39, "refused", "beyond float32's range"),
    "NaN rows": (
        _nan_rows(),
        "refused",
        "3 rows contain NaN or inf; pass --drop-nonfinite to drop them (in Python: read_points",
    ),
    "two points": (SOURCE[:2], "refused", "only 2 point(s); at least 3 are needed"),
    "text": (SOURCE.astype(str), "refused", "expected numbers"),
    "few points": (SOURCE[:6], "warned", "only 6 points; the result is unreliable"),
    "one point far out": (_far_point(), "warned", "times farther out than the median point"),
}  # fmt: skip


@pytest.mark.parametrize("name", list(CASES))
def test_the_cli_and_the_api_give_the_same_verdict(name, tmp_path, capsys, one_thread):
    cloud, verdict, problem = CASES[name]
    np.save(tmp_path / "t.npy", TEMPLATE)
    np.save(tmp_path / "s.npy", cloud)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    code = main(
        [
            "register",
            str(tmp_path / "t.npy"),
            str(tmp_path / "s.npy"),
            "-o",
            str(tmp_path / "out.xyz"),
        ]
    )
    err = capsys.readouterr().err.strip().splitlines()
    if verdict == "refused":
        prefix = f"masknet: error: {tmp_path / 's.npy'}: "
        assert code == 2 and len(err) == 1 and err[0].startswith(prefix), err
        assert problem in err[0]
        assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
        with pytest.raises(MaskNetError) as info:
            register(TEMPLATE, cloud)
        api = str(info.value).replace(ARRAY_NONFINITE_HINT, FILE_NONFINITE_HINT)
        assert api == "source: " + err[0].removeprefix(prefix)  # word for word
    else:
        assert code == 0
        assert [line for line in err if problem in line] == [
            next(line for line in err if problem in line)
        ]
        assert next(line for line in err if problem in line).startswith("masknet: warning: ")
        with pytest.warns(MaskNetWarning, match=problem):
            register(TEMPLATE, cloud)


def test_drop_nonfinite_in_the_api_as_in_the_cli(tmp_path, capsys, one_thread):
    cloud = _nan_rows()
    np.save(tmp_path / "t.npy", TEMPLATE)
    np.save(tmp_path / "s.npy", cloud)
    args = [
        "register",
        str(tmp_path / "t.npy"),
        str(tmp_path / "s.npy"),
        "-o",
        str(tmp_path / "o.xyz"),
    ]
    assert main([*args, "--drop-nonfinite", "--two-sided"]) == 0
    cli_transform = np.loadtxt(tmp_path / "o_transform.txt")
    result = register(TEMPLATE, cloud, drop_nonfinite=True, model=None, method="auto")
    kept = np.isfinite(cloud).all(1)
    assert result.source_mask is None or result.source_mask.shape == (len(cloud),)
    expected = register(TEMPLATE, cloud[kept])
    np.testing.assert_allclose(result.transform, expected.transform, atol=1e-9)
    assert cli_transform.shape == (4, 4)
    two_sided = register(TEMPLATE, cloud, drop_nonfinite=True, iterations=2)
    assert two_sided.source_mask.shape == (len(cloud),)
    assert not two_sided.source_mask[~kept].any() and two_sided.source_mask[kept].mean() > 0.9
    with pytest.raises(MaskNetError, match="one pair"):
        register(TEMPLATE[None], cloud[None], drop_nonfinite=True)


def test_a_3_by_3_array_is_three_points_and_extra_columns_are_dropped():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MaskNetWarning)
        points, rows = check_cloud(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), "x")
    assert points.shape == (3, 3) and rows.all()
    coloured = np.concatenate([SOURCE, RNG.random((200, 3))], axis=1)  # x y z r g b
    np.testing.assert_array_equal(check_cloud(coloured, "x")[0], SOURCE)

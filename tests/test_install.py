"""The base install: registration without the extras' packages, and one line naming the
extra when a feature needs one that is missing."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import masknet._open3d
from masknet import MaskNetError
from masknet.cli import main

# The packages of the extras (pyproject.toml): data, viz, train.
EXTRAS = ("h5py", "tqdm", "matplotlib", "trimesh")

_REGISTER = """
import json, sys
import numpy as np
blocked = {blocked!r}
for name in blocked:
    sys.modules[name] = None  # importing it raises ModuleNotFoundError
import masknet
from masknet.cli import main

rng = np.random.default_rng(0)
template = rng.standard_normal((400, 3))
source = template[:300] @ np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]).T + 0.1
result = masknet.register(template, source)
np.savetxt({folder!r} + "/t.xyz", template)
np.savetxt({folder!r} + "/s.xyz", source)
code = main(["register", {folder!r} + "/t.xyz", {folder!r} + "/s.xyz", "-o", {folder!r} + "/m.xyz"])
loaded = [n for n in {extras!r} if n not in blocked and n in sys.modules]
print(json.dumps({{"code": code, "shape": list(result.transform.shape), "loaded": loaded}}))
"""


def _register_in_subprocess(folder, blocked: tuple[str, ...]) -> dict:
    script = _REGISTER.format(blocked=blocked, folder=str(folder), extras=EXTRAS)
    run = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout.strip().splitlines()[-1])


def test_register_works_without_the_extras(tmp_path):
    """masknet.register and `masknet register` with none of the extras' packages."""
    out = _register_in_subprocess(tmp_path, blocked=EXTRAS)
    assert out == {"code": 0, "shape": [4, 4], "loaded": []}
    assert (tmp_path / "m.xyz").exists()


def test_register_imports_none_of_the_extras(tmp_path):
    """Installed, they stay unimported. tqdm is left out: torch imports it itself when it
    is installed (the run above shows masknet does not need it)."""
    out = _register_in_subprocess(tmp_path, blocked=("tqdm",))
    assert out["code"] == 0 and out["loaded"] == []


def _plot(tmp_path, monkeypatch):
    from masknet.viz import plot_mask

    cloud = np.zeros((4, 3))
    plot_mask(cloud, cloud, np.ones(4, bool), tmp_path / "p.png")


def _progress(tmp_path, monkeypatch):
    from masknet._extras import progress_bar

    list(progress_bar(range(3), disable=True))  # a disabled bar needs no tqdm
    list(progress_bar(range(3)))


def _hdf5(tmp_path, monkeypatch):
    from masknet.data import load_modelnet40

    (tmp_path / "ply_data_test0.h5").write_bytes(b"")
    (tmp_path / "shape_names.txt").write_text("airplane\n")
    load_modelnet40(tmp_path, "test")


def _ply_without_open3d(tmp_path, monkeypatch):
    import masknet.io as mio

    def broken():
        raise ImportError("No module named 'open3d'")

    path = tmp_path / "c.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
        "property float z\nend_header\n0 0 0\n"
    )
    monkeypatch.setattr(masknet._open3d, "_load_open3d", broken)
    mio.read_points(path)


@pytest.mark.parametrize(
    ("package", "extra", "call"),
    [
        ("matplotlib", "viz", _plot),
        ("tqdm", "train", _progress),
        ("h5py", "data", _hdf5),
        ("trimesh", "data", _ply_without_open3d),
    ],
)
def test_missing_extra_is_one_line(tmp_path, monkeypatch, package, extra, call):
    for name in [package, *(n for n in sys.modules if n.startswith(package + "."))]:
        monkeypatch.setitem(sys.modules, name, None)  # as if never installed
    with pytest.raises(MaskNetError) as info:
        call(tmp_path, monkeypatch)
    message = str(info.value)
    assert "\n" not in message
    assert message.endswith(f"needs {package}: pip install 'masknet[{extra}]'")


def test_cli_refuses_a_view_without_matplotlib_before_computing(tmp_path, monkeypatch, capsys):
    cloud = tmp_path / "a.xyz"
    np.savetxt(cloud, np.random.default_rng(0).standard_normal((50, 3)))
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    assert main(["show", str(cloud), "-o", str(tmp_path / "view.html")]) == 2
    err = capsys.readouterr().err
    assert err == "masknet: error: drawing pictures needs matplotlib: pip install 'masknet[viz]'\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.xyz"]

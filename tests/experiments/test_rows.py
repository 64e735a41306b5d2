"""masknet.experiments.rows: a row is resumed only for the same code, weights and shapes."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import masknet
from masknet.experiments import rows


def test_the_fingerprint_follows_the_code(monkeypatch, tmp_path):
    shapes = np.zeros((2, 4, 3))
    before = rows.fingerprint(shapes)
    assert rows.fingerprint(shapes) == before  # deterministic
    assert rows.fingerprint(shapes + 1) != before  # other test shapes
    # A copy of the package with one source file edited gets another fingerprint.
    package = Path(masknet.__file__).parent
    copy = tmp_path / "masknet"
    for path in package.rglob("*.py"):
        target = copy / path.relative_to(package)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(path.read_bytes())
    monkeypatch.setattr(masknet, "__file__", str(copy / "__init__.py"))
    assert rows.fingerprint(shapes) == before
    icp = copy / "registration" / "icp.py"
    icp.write_text(icp.read_text() + "\n# an edit\n")
    assert rows.fingerprint(shapes) != before

"""The resumable row cache: every table row, one JSON line in ``<out>/.rows/<experiment>.jsonl``.

A row is identified by its key, the run's pairs, seed and quick flag, and a
:func:`fingerprint` of what it depends on beyond them (package version, the package's
code, shipped weights, test shapes). ``--resume`` reads matching rows back instead of
computing them: only rows of the same code, so an edit never passes off an old row.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from masknet.io import write_text_atomic
from masknet.models.weights import shipped_weights_path

__all__ = ["append_row", "fingerprint", "read_rows", "row_id"]


def fingerprint(points: np.ndarray) -> str:
    """A digest of the package version, its Python source, every shipped weight file and
    the test shapes (S, N, 3)."""
    from masknet import __file__ as package_init
    from masknet import __version__

    digest = hashlib.sha256(__version__.encode())
    package = Path(package_init).parent
    for path in sorted(package.rglob("*.py")):
        digest.update(str(path.relative_to(package)).encode() + path.read_bytes())
    for path in sorted(shipped_weights_path("").glob("*.safetensors")):
        digest.update(path.name.encode() + path.read_bytes())
    digest.update(np.ascontiguousarray(points).tobytes())
    return digest.hexdigest()[:16]


def row_id(key: dict, pairs: int, seed: int, quick: bool, fingerprint: str) -> str:
    """The identity under which a row is recorded and looked up."""
    ident = json.dumps(
        {**key, "pairs": pairs, "seed": seed, "quick": quick},
        sort_keys=True,
        default=str,
    )
    return ident + f" {fingerprint}"


def read_rows(path: Path) -> dict[str, dict]:
    """id -> entry of a rows file. A line torn by a kill mid-write is ignored, and cut
    off the file, so that the next row appended starts a line of its own."""
    kept = {}
    if path.exists():
        text = path.read_text()
        if text and not text.endswith("\n"):
            text = text[: text.rfind("\n") + 1]
            write_text_atomic(path, text)
        for line in text.splitlines():
            try:
                entry = json.loads(line)
                kept[entry["id"]] = entry
            except (json.JSONDecodeError, KeyError, TypeError):
                continue
    return kept


def append_row(path: Path, entry: dict) -> None:
    """Append one entry (``id``, ``seconds``, ``row``) as a JSON line."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as f:
        f.write(json.dumps(entry) + "\n")

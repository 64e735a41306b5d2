"""The layering of docs/ARCHITECTURE.md: each layer imports only the layers above it."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "masknet"
# The order of docs/ARCHITECTURE.md; a layer may import the ones before it.
LAYERS = [
    "geometry",
    "data",
    "models",
    "registration",
    "training",
    "evaluation",
    "experiments",
    "cli",
]


def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
    return {n for n in names if n.startswith("masknet.")}


def test_no_layer_imports_a_layer_below_it():
    wrong = []
    for rank, layer in enumerate(LAYERS):
        below = LAYERS[rank + 1 :]
        for path in (SRC / layer).rglob("*.py"):
            for name in _imports(path):
                part = name.split(".")[1]
                if part in below:
                    wrong.append(f"{path.relative_to(SRC)} imports {name}")
    assert not wrong, wrong


def test_the_architecture_doc_lists_the_layers_in_this_order():
    text = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    block = text.split("```")[1]
    listed = [line.split()[0] for line in block.strip().splitlines() if re.match(r"^\w", line)]
    assert listed == LAYERS

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


def _imports(path: Path, runtime_only: bool = False) -> set[str]:
    """The masknet modules ``path`` imports; with ``runtime_only``, those under ``if
    TYPE_CHECKING:`` aside (type names only: ``terms/result.py`` names the scene search's
    result type)."""
    tree = ast.parse(path.read_text())
    if runtime_only:
        for node in ast.walk(tree):
            if isinstance(node, ast.If) and getattr(node.test, "id", "") == "TYPE_CHECKING":
                node.body = []
    names = set()
    for node in ast.walk(tree):
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


# registration/'s layout (docs/ARCHITECTURE.md): the call (api, plan, pipeline, many, at the
# package's top) uses everything; the stages use the judge, the solvers and the terms; the
# judge and the solvers never use a stage; the terms use nothing of registration.
CALL = {"api", "plan", "pipeline", "many"}


def test_registration_folders_import_only_down():
    wrong = []
    reg = SRC / "registration"
    for role, banned in (
        ("stages", CALL),
        ("solvers", {"stages"} | CALL),
        ("judge", {"stages"} | CALL),
        ("terms", {"stages", "solvers", "judge"} | CALL),
    ):
        for path in (reg / role).rglob("*.py"):
            for name in _imports(path, runtime_only=True):
                rest = name.removeprefix("masknet.registration.")
                if any(rest == b or rest.startswith(b + ".") for b in banned):
                    wrong.append(f"{path.relative_to(SRC)} imports {name}")
    assert not wrong, wrong
    # the check sees the folders it is about
    assert {p.name for p in reg.iterdir() if p.is_dir()} >= {"terms", "stages", "solvers", "judge"}

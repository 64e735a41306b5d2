"""What the source-tree tests share: the package's paths and its functions by AST."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "masknet"


def top_level_functions() -> list[tuple[str, ast.AST]]:
    """("file:function", node) for every top-level function in src/masknet, and
    ("file:Class", node) for each method of a class (the class is the home)."""
    found = []
    for path in sorted(SRC.rglob("*.py")):
        tree = ast.parse(path.read_text())
        name = path.relative_to(SRC).as_posix()
        for node in tree.body:
            if isinstance(node, ast.ClassDef):
                found += [
                    (f"{name}:{node.name}", item)
                    for item in node.body
                    if isinstance(item, ast.FunctionDef | ast.AsyncFunctionDef)
                ]
            elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                found.append((f"{name}:{node.name}", node))
    return found


def called_names(node: ast.AST) -> set[str]:
    """The names of everything called inside ``node``: ``f(...)`` and ``x.f(...)`` give f."""
    names = set()
    for call in ast.walk(node):
        if isinstance(call, ast.Call):
            func = call.func
            if isinstance(func, ast.Name):
                names.add(func.id)
            elif isinstance(func, ast.Attribute):
                names.add(func.attr)
    return names


def called(node: ast.Call) -> str | None:
    """The name a call calls: ``f(...)`` and ``x.f(...)`` give f; None for anything else."""
    func = node.func
    if isinstance(func, ast.Name):
        return func.id
    return func.attr if isinstance(func, ast.Attribute) else None

"""The shape of the source tree: one home per idea (docs/ARCHITECTURE.md's "One of each"
table), short registration functions, and back-ends that do not import upward."""

from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "masknet"


def one_of_each() -> list[tuple[str, str, str]]:
    """(idea, file relative to src/masknet, name) rows of ARCHITECTURE's table."""
    text = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    table = text.split("<!-- one-of-each -->")[1].split("<!-- /one-of-each -->")[0]
    rows = []
    for line in table.strip().splitlines()[2:]:
        idea, file, name = (cell.strip().strip("`") for cell in line.strip("|").split("|"))
        rows.append((idea, file, name))
    return rows


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


def has_loop(node: ast.AST) -> bool:
    return any(isinstance(n, ast.For | ast.While) for n in ast.walk(node))


def counts_inliers(node: ast.AST) -> bool:
    """The inlier test of a fitness: a squared distance compared with a squared cut-off
    (``d2 <= limit**2``)."""
    for n in ast.walk(node):
        if isinstance(n, ast.Compare) and isinstance(n.ops[0], ast.LtE | ast.Lt):
            right = n.comparators[0]
            if (
                isinstance(right, ast.BinOp)
                and isinstance(right.op, ast.Pow)
                and isinstance(right.right, ast.Constant)
                and right.right.value == 2
            ):
                return True
    return False


def defines_radius(node: ast.AST) -> bool:
    """A cloud's radius: the largest or the RMS distance of its points from a centre
    (``norm(p - c).max()``, ``sqrt(((p - c) ** 2).sum(-1).mean())``)."""
    for n in ast.walk(node):
        if not (isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute | ast.Name)):
            continue
        name = n.func.attr if isinstance(n.func, ast.Attribute) else n.func.id
        for inner in [*n.args, *([n.func.value] if isinstance(n.func, ast.Attribute) else [])]:
            called = called_names(inner)
            centred = any(
                isinstance(b, ast.BinOp) and isinstance(b.op, ast.Sub) for b in ast.walk(inner)
            )
            if name in {"max", "amax"} and "norm" in called and centred:
                return True
            if name == "sqrt" and "mean" in called and centred:
                return True
    return False


NEAREST = {"query", "knn_points", "_nearest", "match"}
RIGID_SOLVES = {"rigid_align", "rigid_transforms_numpy", "_point_to_plane_step"}

# Each detector: the idea's rows of the table, and what marks a definition of it.
DETECTORS = {
    "rotation angle": (
        {
            "rotation angle (atan2, numpy or torch)",
            "turn about the vertical, in a report",
            "turn of the principal axes (a lower bound of a pair's rotation)",
        },
        lambda fn: bool(called_names(fn) & {"arccos", "acos", "arctan2", "atan2"}),
    ),
    "rigid solve": (
        {"rigid solve, torch (weighted Kabsch)", "rigid solve, numpy (the same solve)"},
        lambda fn: "svd" in called_names(fn),
    ),
    "KD-tree": (
        {"KD-tree (pykdtree), built once per cloud"},
        lambda fn: bool(called_names(fn) & {"KDTree", "cKDTree"}),
    ),
    "ICP loop": (
        {idea for idea, _, _ in one_of_each() if "ICP" in idea},
        lambda fn: (
            has_loop(fn)
            and bool(called_names(fn) & NEAREST)
            and bool(called_names(fn) & RIGID_SOLVES)
        ),
    ),
    "radius": (
        {
            "radius of a cloud (the networks' scale)",
            "RMS radius (the frame's scale, the verdict's shifts)",
            "largest distance from the centroid (the robust search's scale, the peers' voxels)",
        },
        defines_radius,
    ),
    "Open3D cloud": (
        {"an Open3D point cloud from arrays (the one builder)"},
        lambda fn: "PointCloud" in called_names(fn),
    ),
    "fitness": (
        {
            idea
            for idea, file, _ in one_of_each()
            if file == "registration/fit.py" or idea.startswith("ICP,") or "consensus" in idea
        },
        counts_inliers,
    ),
}


@pytest.mark.parametrize(("idea", "file", "name"), one_of_each())
def test_every_home_in_the_table_exists(idea, file, name):
    module = importlib.import_module("masknet." + file.removesuffix(".py").replace("/", "."))
    assert hasattr(module, name), f"{idea}: {file} has no {name}"


@pytest.mark.parametrize("detector", sorted(DETECTORS))
def test_no_idea_is_defined_outside_its_home(detector):
    ideas, marks = DETECTORS[detector]
    homes = {f"{file}:{name}" for idea, file, name in one_of_each() if idea in ideas}
    assert homes, f"no row of the table is a {detector}"
    found = {where for where, fn in top_level_functions() if marks(fn)}
    assert found - homes == set(), f"a {detector} outside the table: {sorted(found - homes)}"
    assert found, f"the {detector} detector finds nothing: it no longer sees its idea"


def body_lines(fn: ast.FunctionDef) -> int:
    body = fn.body
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
        body = body[1:]  # the docstring
    return 0 if not body else body[-1].end_lineno - body[0].lineno + 1


def test_register_and_the_registration_functions_are_short():
    long = {
        where: body_lines(fn)
        for where, fn in top_level_functions()
        if where.startswith("registration/") and body_lines(fn) >= 80
    }
    assert not long, f"functions of 80 lines or more: {long}"
    register = dict(top_level_functions())["registration/api.py:register"]
    assert body_lines(register) < 60


def test_backends_import_nothing_that_dispatches_into_them():
    dispatchers = set()
    for path in (SRC / "registration").glob("*.py"):
        if re.search(r"^from masknet\.registration\.(methods|backends)", path.read_text(), re.M):
            dispatchers.add("masknet.registration." + path.stem)
    assert "masknet.registration.rounds" in dispatchers  # the check still sees a dispatcher
    for path in (SRC / "registration" / "backends").glob("*.py"):
        imported = re.findall(r"from (masknet\.[\w.]+) import", path.read_text())
        assert not set(imported) & dispatchers, f"{path.name} imports {set(imported) & dispatchers}"


@pytest.mark.parametrize(
    ("old", "name", "new"),
    [
        ("masknet.registration.prepared", "pose_fit", "masknet.registration.fit"),
        ("masknet.registration.prepared", "PoseFit", "masknet.registration.fit"),
        ("masknet.registration.rounds", "RoundFits", "masknet.registration.fit"),
        ("masknet.registration.rounds", "keep_source_points", "masknet.registration.backends.base"),
        ("masknet.registration.refinement", "FIT_SLACK", "masknet.registration.fit"),
        ("masknet.registration.api", "REFINE_POINTS", "masknet.registration.pipeline"),
        (
            "masknet.registration.coarse",
            "coarse_to_fine",
            "masknet.registration.robust.search",
        ),
        ("masknet.registration.coarse", "check_points", "masknet.registration.prepared"),
        ("masknet.registration.evaluation", "evaluate_registration", "masknet.registration.fit"),
        ("masknet.registration.sampling", "fit_to_network", "masknet.geometry.sampling"),
    ],
)
def test_a_moved_name_still_imports_with_a_warning_naming_its_new_place(old, name, new):
    module = importlib.import_module(old)
    with pytest.warns(DeprecationWarning, match=f"{new}.{name}"):
        value = getattr(module, name)
    assert value is getattr(importlib.import_module(new), name)
    with pytest.raises(AttributeError):
        module.no_such_name  # noqa: B018

"""The shape of the source tree: one home per idea (docs/ARCHITECTURE.md's "One of each"
table), short functions (registration's shortest), back-ends that do not import upward, and
the old module paths that still import. No pose compared with another outside the arbiter:
tests/test_arbiter_rule.py."""

from __future__ import annotations

import ast
import importlib
import importlib.util
import re
from pathlib import Path

import pytest

import source_tree  # tests/source_tree.py, on pytest's pythonpath

ROOT, SRC = source_tree.ROOT, source_tree.SRC
top_level_functions, called_names = source_tree.top_level_functions, source_tree.called_names
_called = source_tree.called


def one_of_each() -> list[tuple[str, str, str]]:
    """(idea, file relative to src/masknet, name) rows of ARCHITECTURE's table."""
    text = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    table = text.split("<!-- one-of-each -->")[1].split("<!-- /one-of-each -->")[0]
    rows = []
    for line in table.strip().splitlines()[2:]:
        idea, file, name = (cell.strip().strip("`") for cell in line.strip("|").split("|"))
        rows.append((idea, file, name))
    return rows


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


def _norm_points(node: ast.AST) -> ast.AST | None:
    """The points of a norm call (``np.linalg.norm(x, ...)``: x; ``x.norm(...)``: x), or
    None where ``node`` is no norm call."""
    if not (isinstance(node, ast.Call) and _called(node) == "norm"):
        return None
    func = node.func
    numpy = isinstance(func, ast.Name) or (
        isinstance(func.value, ast.Attribute | ast.Name)
        and (func.value.attr if isinstance(func.value, ast.Attribute) else func.value.id)
        in {"linalg", "np", "numpy"}
    )
    if numpy:
        return node.args[0] if node.args else None
    return func.value


def _reduced(call: ast.Call) -> ast.AST | None:
    """What a reduction reduces: its receiver (``x.max()``), or the first argument of a
    module's function (``np.max(x)``); None for a builtin's ``max(a, b)``."""
    func = call.func
    if not isinstance(func, ast.Attribute):
        return None
    if isinstance(func.value, ast.Name) and func.value.id in {"np", "numpy", "torch"}:
        return call.args[0] if call.args else None
    return func.value


def _less_its_mean(node: ast.AST) -> bool:
    """``p - p.mean(...)``: points less their centroid."""
    return (
        isinstance(node, ast.BinOp)
        and isinstance(node.op, ast.Sub)
        and "mean" in called_names(node.right)
    )


def defines_radius(node: ast.AST) -> bool:
    """A cloud's radius: the largest or the RMS distance of its points from a centre
    (``norm(p - c).max()``, ``sqrt(((p - c) ** 2).sum(-1).mean())``), also where the points
    were centred before (``norm(centred, axis=1).max()``, ``x.norm(dim=-1).amax(1)``), and
    their mean distance from their centroid (``norm(p - p.mean(0), axis=1).mean()``). The
    largest norm of a difference of two clouds (an error) is none."""
    for n in ast.walk(node):
        if not (isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute | ast.Name)):
            continue
        name = _called(n)
        receiver = [n.func.value] if isinstance(n.func, ast.Attribute) else []
        for inner in [*n.args, *receiver]:
            called = called_names(inner)
            centred = any(
                isinstance(b, ast.BinOp) and isinstance(b.op, ast.Sub) for b in ast.walk(inner)
            )
            if name in {"max", "amax"} and "norm" in called and centred:
                return True
            if name == "sqrt" and "mean" in called and centred:
                return True
            if inner is not _reduced(n):
                continue
            points = _norm_points(inner)
            if points is None or name not in {"max", "amax", "mean"}:
                continue
            if _less_its_mean(points):  # the mean distance too
                return True
            if name != "mean" and isinstance(points, ast.Name | ast.Attribute):
                return True  # points centred before
    return False


def cosine_from_trace(node: ast.AST) -> bool:
    """A rotation's cosine from its trace, ``(trace - 1) / 2`` (then an arccos, or a test
    against a cosine): the trace a name ``trace``, or ``np.trace``, ``einsum``,
    ``diagonal`` of the matrices."""
    for n in ast.walk(node):
        if not (isinstance(n, ast.BinOp) and isinstance(n.op, ast.Div)):
            continue
        left, right = n.left, n.right
        if not (isinstance(right, ast.Constant) and right.value == 2):
            continue
        if not (isinstance(left, ast.BinOp) and isinstance(left.op, ast.Sub)):
            continue
        if not (isinstance(left.right, ast.Constant) and left.right.value == 1):
            continue
        names = called_names(left.left) | {
            m.id for m in ast.walk(left.left) if isinstance(m, ast.Name)
        }
        if names & {"trace", "einsum", "diagonal", "diag"}:
            return True
    return False


CUTOFF_SPACINGS = {"DEFAULT_SPACINGS", "FIT_SPACINGS"}


def _named(node: ast.AST) -> str:
    if isinstance(node, ast.Name):
        return node.id
    return node.attr if isinstance(node, ast.Attribute) else ""


def sets_inlier_cutoff(node: ast.AST) -> bool:
    """The inlier cut-off of a cloud: ``DEFAULT_SPACINGS`` (or its alias ``FIT_SPACINGS``)
    times anything, or ``1.5`` times a spacing (a name holding "spacing", a call of
    ``median_spacing``)."""
    for n in ast.walk(node):
        if not (isinstance(n, ast.BinOp) and isinstance(n.op, ast.Mult)):
            continue
        for factor, other in ((n.left, n.right), (n.right, n.left)):
            if _named(factor) in CUTOFF_SPACINGS:
                return True
            spacing = any("spacing" in _named(m).lower() for m in ast.walk(other))
            if isinstance(factor, ast.Constant) and factor.value == 1.5 and spacing:
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
        lambda fn: (
            bool(called_names(fn) & {"arccos", "acos", "arctan2", "atan2"}) or cosine_from_trace(fn)
        ),
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
            "largest distance from the centroid (the robust search's scale)",
        },
        defines_radius,
    ),
    "inlier cut-off": (
        {"the inlier cut-off of a cloud (1.5 of its spacings)"},
        sets_inlier_cutoff,
    ),
    "Open3D cloud": (
        {"an Open3D point cloud from arrays (the one builder)"},
        lambda fn: "PointCloud" in called_names(fn),
    ),
    "fitness": (
        {
            idea
            for idea, file, _ in one_of_each()
            if file == "registration/judge/fit.py" or idea.startswith("ICP,") or "consensus" in idea
        },
        counts_inliers,
    ),
}


@pytest.mark.parametrize(("idea", "file", "name"), one_of_each())
def test_every_home_in_the_table_exists(idea, file, name):
    module = importlib.import_module("masknet." + file.removesuffix(".py").replace("/", "."))
    assert hasattr(module, name), f"{idea}: {file} has no {name}"


# (detector, file:function) -> why that definition stays outside the idea's home.
ELSEWHERE = {
    ("radius", "data/modelnet.py:normalize_unit_sphere"): (
        "ModelNet40's shapes are float32: unit_radius's float64 radius moves them by up to "
        "1.2e-7 (a float32 step), and every figure was measured on the shapes as they are"
    ),
    ("rotation angle", "geometry/fpfh.py:_atan2_binned"): (
        "FPFH's pair-feature angle between two normals (Open3D's atan2, binned), no rotation"
    ),
    ("inlier cut-off", "registration/judge/prepared.py:prepare_check"): (
        "the verdict's cut-off, on the larger of the two clouds' spacings; it goes through "
        "options.inlier_cutoff with the verdict's next change"
    ),
}


@pytest.mark.parametrize("detector", sorted(DETECTORS))
def test_no_idea_is_defined_outside_its_home(detector):
    ideas, marks = DETECTORS[detector]
    homes = {f"{file}:{name}" for idea, file, name in one_of_each() if idea in ideas}
    assert homes, f"no row of the table is a {detector}"
    found = {where for where, fn in top_level_functions() if marks(fn)}
    allowed = {where for kind, where in ELSEWHERE if kind == detector}
    outside = found - homes - allowed
    assert outside == set(), f"a {detector} outside the table: {sorted(outside)}"
    assert allowed <= found, f"listed in ELSEWHERE but gone: {sorted(allowed - found)}"
    assert found, f"the {detector} detector finds nothing: it no longer sees its idea"


def _marked(detector: str, code: str) -> bool:
    return DETECTORS[detector][1](ast.parse(code).body[0])


@pytest.mark.parametrize(
    ("detector", "code"),
    [
        ("radius", "def f(p):\n    return np.linalg.norm(p - p.mean(0), axis=1).max()"),
        ("radius", "def f(p):\n    c = p - p.mean(0)\n    return np.linalg.norm(c, axis=1).max()"),
        ("radius", "def f(p):\n    return float(np.max(np.linalg.norm(p, axis=1)))"),
        ("radius", "def f(p):\n    return p.norm(dim=-1).amax(1)"),
        ("radius", "def f(p):\n    return np.linalg.norm(p - p.mean(0), axis=1).mean()"),
        ("rotation angle", "def f(a, b):\n    return np.arccos((np.trace(a.T @ b) - 1) / 2)"),
        (
            "rotation angle",
            "def f(p, r, c):\n    return (np.einsum('hij,ij->h', p, r) - 1) / 2 > c",
        ),
        ("inlier cut-off", "def f(t):\n    return FIT_SPACINGS * median_spacing(t)"),
        ("inlier cut-off", "def f(pair):\n    return DEFAULT_SPACINGS * pair.spacing"),
        ("inlier cut-off", "def f(t):\n    return 1.5 * median_spacing(t)"),
        ("inlier cut-off", "def f(spacing):\n    return spacing * 1.5"),
    ],
)
def test_each_detector_sees_a_planted_definition(detector, code):
    assert _marked(detector, code)


@pytest.mark.parametrize(
    ("detector", "code"),
    [
        ("radius", "def f(v):\n    return v / max(np.linalg.norm(v), 1e-12)"),
        ("radius", "def f(a, b):\n    return np.linalg.norm(a - b, axis=1).mean()"),
        ("rotation angle", "def f(n, w):\n    return w * (n - 1) / 2"),
        ("inlier cut-off", "def f(voxel):\n    return 1.5 * voxel"),
        ("inlier cut-off", "def f(spacing):\n    return 2.0 * spacing"),
    ],
)
def test_each_detector_passes_over_what_defines_nothing(detector, code):
    assert not _marked(detector, code)


def body_lines(fn: ast.FunctionDef) -> int:
    """Lines from the first statement after the docstring to the function's end line."""
    body = fn.body
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
        body = body[1:]  # the docstring
    return 0 if not body else fn.end_lineno - body[0].lineno + 1


def every_function(root: Path = SRC) -> list[tuple[str, ast.AST]]:
    """("file:line:name", node) for every function under ``root``: top-level, methods,
    and functions nested in either."""
    found = []
    for path in sorted(root.rglob("*.py")):
        name = path.relative_to(root).as_posix()
        found += [
            (f"{name}:{node.lineno}:{node.name}", node)
            for node in ast.walk(ast.parse(path.read_text()))
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
        ]
    return found


def test_no_function_body_is_over_80_lines():
    long = {where: n for where, fn in every_function() if (n := body_lines(fn)) > 80}
    assert not long, f"function bodies over 80 lines (split them into named helpers): {long}"


def test_the_length_check_sees_nested_functions_and_skips_docstrings(tmp_path):
    lines = ["class C:", "    def f(self):", '        """A docstring', *["        line"] * 30]
    lines += ['        """', "        def g():", *[f"            x{i} = {i}" for i in range(81)]]
    (tmp_path / "m.py").write_text("\n".join(lines) + "\n")
    lengths = {where: body_lines(fn) for where, fn in every_function(tmp_path)}
    assert lengths == {"m.py:2:f": 82, "m.py:35:g": 81}  # the 32 docstring lines not counted


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
    backends = SRC / "registration" / "solvers" / "backends"
    for path in (SRC / "registration").rglob("*.py"):
        text = path.read_text()
        if backends not in path.parents and re.search(
            r"^from masknet\.registration\.(terms\.methods|solvers\.backends)", text, re.M
        ):
            dispatchers.add(".".join(path.relative_to(SRC.parent).with_suffix("").parts))
    assert "masknet.registration.stages.rounds" in dispatchers  # the check still sees a dispatcher
    for path in backends.glob("*.py"):
        imported = re.findall(r"from (masknet\.[\w.]+) import", path.read_text())
        assert not set(imported) & dispatchers, f"{path.name} imports {set(imported) & dispatchers}"


@pytest.mark.parametrize(
    ("old", "name", "new"),
    [
        ("masknet.registration.auto", "auto_register", "masknet.registration.stages.auto"),
        ("masknet.registration.robust", "robust_register", "masknet.registration.stages.robust"),
        ("masknet.registration.robust.consensus", "judge", "masknet.registration.stages.consensus"),
        ("masknet.registration.icp", "icp", "masknet.registration.solvers.icp"),
        ("masknet.registration.backends", "BackendRun", "masknet.registration.solvers.backends"),
        ("masknet.registration.arbiter", "Candidate", "masknet.registration.judge.arbiter"),
        ("masknet.registration.options", "ICPCriteria", "masknet.registration.terms.options"),
    ],
)
def test_a_moved_module_still_imports_with_a_warning_naming_its_new_place(old, name, new):
    module = importlib.import_module(old)
    with pytest.warns(DeprecationWarning, match=f"{old} has moved to {new}"):
        value = getattr(module, name)
    assert value is getattr(importlib.import_module(new), name)


def test_every_registration_module_is_the_call_or_in_a_role_folder_or_a_shim():
    loose = [
        path.relative_to(SRC).as_posix()
        for path in (SRC / "registration").rglob("*.py")
        if path.parent.name not in {"terms", "stages", "solvers", "judge", "backends"}
        and path.name not in {"__init__.py", "api.py", "plan.py", "pipeline.py", "many.py"}
        and "moved_" not in path.read_text()
    ]
    assert not loose, f"modules outside the role folders: {loose}"


@pytest.mark.parametrize(
    ("old", "name", "new"),
    [
        ("masknet.registration.judge.prepared", "pose_fit", "masknet.registration.judge.fit"),
        ("masknet.registration.judge.prepared", "PoseFit", "masknet.registration.judge.fit"),
        ("masknet.registration.stages.rounds", "RoundFits", "masknet.registration.judge.fit"),
        (
            "masknet.registration.stages.rounds",
            "keep_source_points",
            "masknet.registration.solvers.backends.base",
        ),
        ("masknet.registration.stages.refinement", "FIT_SLACK", "masknet.registration.judge.fit"),
        ("masknet.registration.api", "REFINE_POINTS", "masknet.registration.pipeline"),
        (
            "masknet.registration.coarse",
            "coarse_to_fine",
            "masknet.registration.stages.search",
        ),
        ("masknet.registration.coarse", "check_points", "masknet.registration.judge.prepared"),
        (
            "masknet.registration.evaluation",
            "evaluate_registration",
            "masknet.registration.judge.fit",
        ),
        ("masknet.registration.sampling", "fit_to_network", "masknet.geometry.sampling"),
        ("masknet.registration.judge.fit", "fits_worse", "masknet.registration.judge.arbiter"),
        (
            "masknet.registration.stages.consensus",
            "verdict_rank",
            "masknet.registration.judge.arbiter",
        ),
        ("masknet.registration.judge.hypotheses", "rank", "masknet.registration.judge.arbiter"),
    ],
)
def test_a_moved_name_still_imports_with_a_warning_naming_its_new_place(old, name, new):
    module = importlib.import_module(old)
    with pytest.warns(DeprecationWarning, match=f"{new}.{name}"):
        value = getattr(module, name)
    assert value is getattr(importlib.import_module(new), name)
    with pytest.raises(AttributeError):
        module.no_such_name  # noqa: B018


MAX_FILE_LINES = 500  # a module longer than this holds more than one idea: split it


def long_modules(root: Path = SRC) -> dict[str, int]:
    """Modules under ``root`` longer than ``MAX_FILE_LINES``, by path: their line counts."""
    counts = {str(p.relative_to(root)): len(p.read_text().splitlines()) for p in root.rglob("*.py")}
    return {path: n for path, n in counts.items() if n > MAX_FILE_LINES}


def test_no_module_is_over_500_lines():
    assert not long_modules(), f"modules over {MAX_FILE_LINES} lines: {long_modules()}"


def test_a_long_module_is_found(tmp_path):
    (tmp_path / "short.py").write_text("x = 1\n" * MAX_FILE_LINES)
    (tmp_path / "long.py").write_text("x = 1\n" * (MAX_FILE_LINES + 1))
    assert long_modules(tmp_path) == {"long.py": MAX_FILE_LINES + 1}

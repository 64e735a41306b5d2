"""No pose is compared with another outside the arbiter (registration/judge/arbiter.py), by
AST over registration/ and tracking/ (docs/ARCHITECTURE.md)."""

from __future__ import annotations

import ast

import source_tree  # tests/source_tree.py, on pytest's pythonpath

ROOT, SRC = source_tree.ROOT, source_tree.SRC
top_level_functions, called_names = source_tree.top_level_functions, source_tree.called_names
_called = source_tree.called

# --- No pose is compared with another outside registration/judge/arbiter.py ------------------
#
# The rule, by AST over ``src/masknet/registration/**`` and ``src/masknet/tracking/**``
# (every top-level function and every method), arbiter.py aside:
#
# * A **measure** is an attribute or a local name one of whose ``_``-separated words is a
#   measure word (score, fitness, fit, fits, rmse, verdict, overlap, rank, coverage:
#   ``c.score``, ``new_fit``, ``info["runner_up_score"]``), a call of a function that
#   measures or compares poses (``pose_fit``, ``judge``, ``verdict_rank``,
#   ``rotation_between_deg``, ``trimmed_fit``, ``matches_within``, ...), or a local name
#   assigned from a measure anywhere in the function (``right = fit.fitness``). Upper-case
#   names are constants (thresholds), never measures; a called function's own name does
#   not count, nor a name before a dot by its words alone (``fit.RoundFits``, a module).
# * A comparison (``<``, ``<=``, ``>``, ``>=``, ``==``, ``!=``) is a **decision** where a
#   measure meets another measure or a value that is not a constant: two poses' measures,
#   or a measure against a threshold the caller chose (an early exit). A measure against
#   a literal or an upper-case constant (``overlap_fit < WRONG_FIT``) judges one pose on a
#   fixed bound, and is not.
# * A pick (``min``, ``max``, ``sorted``, ``.sort``, ``argsort``, ``argmax``, ``argmin``)
#   is a decision where any of its arguments, its key or its receiver is a measure.
#
# Any decision outside arbiter.py fails, except those of ALLOWED, each with the reason it
# is not a choice between poses.

WORDS = {
    "score",
    "scores",
    "fitness",
    "fit",
    "fits",
    "rmse",
    "verdict",
    "overlap",
    "rank",
    "coverage",
}
CALLS = {
    "rotation_between_deg",
    "verdict_rank",
    "rank",
    "pose_fit",
    "pose_fits",
    "judge",
    "trimmed_fit",
    "trimmed_mean",
    "_scores",
    "_refined",
    "refine",
    "refined",
    "matches_within",
}
PICKS = {"min", "max", "sorted", "sort", "argsort", "argmax", "argmin"}
COMPARISONS = (ast.Lt, ast.LtE, ast.Gt, ast.GtE, ast.Eq, ast.NotEq)

ARBITER = "registration/judge/arbiter.py:"
# (file:function, the decision's source) -> why it is no choice between poses.
ALLOWED = {
    ("registration/stages/auto.py:_fast_path", "len(fine_template) == len(template)"): (
        "a count of rows, not a pose: whether the fit view holds the whole template, so that"
        " its KD-tree serves the returned mask (``fine_template`` is read as a measure because"
        " it comes from the pair's ``fit`` view)"
    ),
    ("tracking/tracker.py:Tracker", "self._uncertain < self.max_uncertain"): (
        "a count of uncertain frames in a row against the caller's limit (``self`` is read as"
        " a measure where a method assigns it from a verdict)"
    ),
    ("tracking/tracker.py:_quick_check", "min(source_fit, template_fit)"): (
        "the tracker's quick verdict's overlap fit of one pose: the worse of its two directions"
    ),
    ("registration/solvers/correspondences.py:ransac_poses", "max(best, int(near.sum(1).max()))"): (
        "RANSAC's stopping rule (how many draws): the best inlier share so far"
    ),
    ("registration/solvers/correspondences.py:ransac_poses", "near.sum(1).max()"): (
        "RANSAC's stopping rule (how many draws): the best inlier share so far"
    ),
    (
        "registration/solvers/correspondences.py:ransac_poses",
        "drawn >= np.log(1 - confidence) / np.log(1 - share ** 3)",
    ): "RANSAC's stopping rule: enough draws for its confidence",
    ("registration/solvers/icp.py:_settled", "change <= relative_rmse * prev_mse ** 0.5"): (
        "ICP's convergence test on its own iterates' error, not a choice of answer"
    ),
    ("registration/stages/scene_centres.py:likely_centres", "np.argsort(-scores, kind='stable')"): (
        "ranks the scene's candidate centres by feature likeness, before any pose exists"
    ),
}


def _words(name: str) -> set[str]:
    return set(name.lower().split("_"))


def _receivers(root: ast.AST) -> tuple[set[int], set[int]]:
    """(called, before a dot): the ids of names that are a called function's, and of
    names before a dot (``fit.RoundFits``: a module, whose attribute decides)."""
    called, before = set(), set()
    for node in ast.walk(root):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            called.add(id(node.func))
        elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
            before.add(id(node.value))
    return called, before


def is_measure(node: ast.AST, tainted: set[str]) -> bool:
    """Whether ``node`` holds a measure (the rule above). A name before a dot counts only
    where it was assigned from a measure (``near.sum(1)``), not by its words."""
    called, before = _receivers(node)
    for n in ast.walk(node):
        if isinstance(n, ast.Attribute) and not n.attr.isupper() and _words(n.attr) & WORDS:
            return True
        if isinstance(n, ast.Name) and id(n) not in called and not n.id.isupper():
            if n.id in tainted or (id(n) not in before and _words(n.id) & WORDS):
                return True
        if isinstance(n, ast.Subscript) and isinstance(n.slice, ast.Constant):
            if isinstance(n.slice.value, str) and _words(n.slice.value) & WORDS:
                return True
        if isinstance(n, ast.Call) and _called(n) in CALLS:
            return True
    return False


def is_constant(node: ast.AST) -> bool:
    """A literal, an upper-case name, or arithmetic of them."""
    if isinstance(node, ast.Constant):
        return True
    if isinstance(node, ast.Name | ast.Attribute):
        return (node.id if isinstance(node, ast.Name) else node.attr).isupper()
    if isinstance(node, ast.UnaryOp):
        return is_constant(node.operand)
    if isinstance(node, ast.BinOp):
        return is_constant(node.left) and is_constant(node.right)
    return False


def _tainted(fn: ast.AST) -> set[str]:
    """Local names assigned from a measure anywhere in ``fn`` (to a fixed point)."""
    tainted: set[str] = set()
    while True:
        size = len(tainted)
        for n in ast.walk(fn):
            if isinstance(n, ast.Assign | ast.AnnAssign | ast.AugAssign) and n.value:
                targets = n.targets if isinstance(n, ast.Assign) else [n.target]
                if is_measure(n.value, tainted):
                    tainted |= {
                        t.id for x in targets for t in ast.walk(x) if isinstance(t, ast.Name)
                    }
            elif isinstance(n, ast.For | ast.comprehension) and is_measure(n.iter, tainted):
                tainted |= {t.id for t in ast.walk(n.target) if isinstance(t, ast.Name)}
        if len(tainted) == size:
            return tainted


def decisions(fn: ast.AST) -> list[str]:
    """The source of every decision between poses in ``fn`` (the rule above)."""
    tainted = _tainted(fn)
    found = []
    for n in ast.walk(fn):
        if isinstance(n, ast.Compare) and all(isinstance(o, COMPARISONS) for o in n.ops):
            sides = [n.left, *n.comparators]
            measured = [is_measure(s, tainted) for s in sides]
            loose = [not m and not is_constant(s) for s, m in zip(sides, measured, strict=True)]
            if sum(measured) >= 2 or (any(measured) and any(loose)):
                found.append(ast.unparse(n))
        elif isinstance(n, ast.Call) and _called(n) in PICKS:
            parts = [*n.args, *(k.value for k in n.keywords)]
            if isinstance(n.func, ast.Attribute):
                parts.append(n.func.value)
            if any(is_measure(p, tainted) for p in parts):
                found.append(ast.unparse(n))
    return found


CHECKED = ("registration/", "tracking/")  # the folders whose poses only the arbiter compares


def registration_decisions() -> set[tuple[str, str]]:
    """("file:function", source) of every decision in the folders of CHECKED."""
    return {
        (where, text)
        for where, fn in top_level_functions()
        if where.startswith(CHECKED)
        for text in decisions(fn)
    }


def test_no_pose_is_compared_outside_the_arbiter():
    found = {d for d in registration_decisions() if not d[0].startswith(ARBITER)}
    outside = sorted(found - set(ALLOWED))
    assert not outside, f"decisions between poses outside arbiter.py: {outside}"
    stale = sorted(set(ALLOWED) - found)
    assert not stale, f"allowed decisions that are gone (drop them from ALLOWED): {stale}"


def test_the_tracker_is_checked_and_ranks_through_the_arbiter():
    """The tracker's files are read, and its pick of a candidate is the arbiter's rule
    (its former key, verdict then fitness, was a decision)."""
    checked = {where for where, _ in top_level_functions() if where.startswith(CHECKED)}
    assert "tracking/tracker.py:_best" in checked
    assert _found("def _best(c):\n    return min(c, key=lambda c: (RANKS[c.verdict], -c.fitness))")
    tracker = (SRC / "tracking" / "tracker.py").read_text()
    best = next(n for n in ast.parse(tracker).body if getattr(n, "name", "") == "_best")
    assert "best_judged" in called_names(best)


def test_the_arbiter_holds_the_decisions():
    """The detector sees the arbiter's own rules: it still recognises its idea."""
    rules = {where.split(":")[1] for where, _ in registration_decisions() if ARBITER in where}
    expected = {"fits_better", "within_gap", "least_turned", "accepts", "exits", "fits_worse"}
    expected |= {"displaces", "ranks_higher", "apart", "same_place", "lowest", "polished"}
    assert expected <= rules


def _found(code: str) -> list[str]:
    return decisions(ast.parse(code).body[0])


def test_the_detector_sees_each_kind_of_decision():
    assert _found("def f(a, b):\n    return a.score > b.score")
    assert _found("def f(c):\n    return sorted(c, key=rank)")
    assert _found("def f(c):\n    return max(c, key=lambda x: x.fitness)")
    assert _found("def f(fits, level):\n    return max(f.fitness for f in fits) >= level")
    assert _found("def f(fit, accept):\n    right = fit.fitness\n    return right >= accept")
    assert _found("def f(a, b, d):\n    return rotation_between_deg(a, b) < d")
    assert _found("def f(p):\n    return np.argsort(trimmed_fit(p))")
    assert _found("def f(a, b):\n    return verdict_rank(a) > verdict_rank(b)")
    assert _found("def f(run, s):\n    return run.info['score'][0] < s")
    assert _found("def f(a, best):\n    return a.score < best - GAP")


def test_the_detector_passes_over_what_decides_nothing():
    assert not _found("def f(m):\n    return m.fitness > 0")  # a literal bound
    assert not _found("def f(overlap_fit):\n    return overlap_fit < WRONG_FIT")  # a constant
    assert not _found("def f(f, winner):\n    return f is not winner")  # identity
    assert not _found("def f(x):\n    return fit.RoundFits(x) > 0")  # a module's name
    assert not _found("def f(a, b):\n    return len(a) < len(b)")

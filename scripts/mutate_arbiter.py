"""A mutation pass over the arbiter: each rule disabled or inverted, one at a time.

    python scripts/mutate_arbiter.py -o docs/results/arbiter_mutants
    python scripts/mutate_arbiter.py --only fits_better --tests tests/registration/judge/test_arbiter.py

Each mutant of MUTANTS replaces one exact piece of text inside one rule function of
src/masknet/registration/judge/arbiter.py (the text must occur exactly once in that
function, or the pass stops: it cannot silently test nothing). The mutated module is
written to a temporary copy of src/, put first on PYTHONPATH (no bytecode is written, so
no stale cache can stand in for it); the real file is never touched. The chosen tests
then run with ``pytest -x`` (the arbiter's own unit tests first), and the mutant is
caught when one fails: the first failing test is recorded. An unmutated run of the same
tests comes first and must pass. Options this script does not know go to pytest (``-k``,
``--ignore``). Writes mutants.json and mutants.md to ``-o``.
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

from masknet.cli import run_script
from masknet.errors import MaskNetError

ROOT = Path(__file__).resolve().parents[1]
ARBITER = Path("masknet/registration/judge/arbiter.py")  # under src/
# The arbiter's unit tests first (-x stops at the first failure), then every test folder
# whose code reaches the arbiter: the registration stages and the tracker.
TESTS = ("tests/registration/judge/test_arbiter.py", "tests/registration", "tests/tracking")


class Mutant(NamedTuple):
    """One change to one rule: ``old`` (exact text, once in the function ``rule``) becomes
    ``new``. ``does``: what the mutant does, in words. ``equivalent``: why it cannot be
    observed, where it cannot (empty otherwise)."""

    rule: str
    kind: str
    old: str
    new: str
    does: str
    equivalent: str = ""

    @property
    def name(self) -> str:
        """``rule/kind``, e.g. ``fits_better/inverted``."""
        return f"{self.rule}/{self.kind}"


M = Mutant
# fmt: off
MUTANTS: tuple[Mutant, ...] = (
    # --- The pipelines' score
    M("rank", "score-inverted", "return candidate.score,", "return -candidate.score,",
      "the lower score ranks first"),
    M("rank", "rmse-inverted", "-candidate.rmse", "candidate.rmse",
      "the higher RMSE breaks a tie"),
    M("best_first", "worst-first", "reverse=True", "reverse=False", "worst first"),
    M("best_first", "equals-reversed", "sorted(candidates, key=key, reverse=True)",
      "sorted(candidates[::-1], key=key, reverse=True)", "equals in reverse order"),
    M("best_score", "lowest", "max(c.score", "min(c.score", "the lowest score"),
    M("fits_better", "inverted", "candidate.score > score", "candidate.score < score",
      "a lower score displaces"),
    M("fits_better", "tie-displaces", "candidate.score > score", "candidate.score >= score",
      "a tie displaces the held answer"),
    M("within_gap", "inverted", "score >= best - gap", "score < best - gap",
      "only scores beyond the gap"),
    M("within_gap", "no-gap", "score >= best - gap", "score >= best", "the gap ignored"),
    M("alike", "inverted", "if within_gap(", "if not within_gap(", "those beyond the margin"),
    M("alike", "first-only", "return [c for c in ordered if", "return [c for c in ordered[:1] if",
      "only the first is ever alike"),
    M("least_turned", "most-turned", "return min(candidates", "return max(candidates",
      "the most turned wins"),
    M("least_turned", "last-on-tie", "return min(candidates,", "return min(candidates[::-1],",
      "the last on a tie"),
    M("runner_up", "same-basin", "c is not winner and apart(", "c is not winner and not apart(",
      "the first pose near the winner"),
    M("runner_up", "none", "(c for c in ordered if", "(c for c in ordered[:0] if",
      "never a runner-up"),
    M("close_rival", "beyond-margin", "and within_gap(", "and not within_gap(",
      "a rival beyond the margin"),
    M("close_rival", "same-basin", "if apart(", "if not apart(", "a rival near the held pose"),
    # --- The search's choice
    M("search_choice", "no-merge", "finals = one_per_basin(best_first(finals), len(finals), limit)",
      "finals = best_first(finals)", "answers in one basin stay two"),
    M("search_choice", "no-refine", "if len(alike_now) > 1:", "if False:",
      "alike answers not re-ranked by their refined score"),
    M("search_choice", "first-wins", "winner = least_turned(alike_now)",
      "winner = alike_now[0]", "the best scored of the alike wins, not the least turned"),
    M("search_choice", "ambiguity-inverted", "rival is not None and within_gap(",
      "rival is not None and not within_gap(", "ambiguous when the rival is beyond the margin"),
    # --- Early exits and guards
    M("accepts", "inverted", "fitness >= level", "fitness < level", "accepts below the level"),
    M("accepts", "strict", "fitness >= level", "fitness > level", "the level itself not accepted"),
    M("exits", "worst", "max(f.fitness", "min(f.fitness", "exits on the worst fit"),
    M("fits_worse", "inverted", "new_score < start_score", "new_score >= start_score",
      "undoes the rounds that held"),
    M("fits_worse", "no-slack", "start_score - FIT_SLACK", "start_score",
      "no slack: any loss undoes the round"),
    # --- The verdict
    M("verdict_rank", "verdict-inverted", "-VERDICTS.index(", "VERDICTS.index(",
      "worse verdicts first"),
    M("verdict_rank", "overlap-inverted", ", check.overlap_fit", ", -check.overlap_fit",
      "the smaller overlap fit first"),
    M("best_judged", "worst", "return max(candidates", "return min(candidates",
      "the worst judged"),
    M("best_judged", "last-on-tie", "return max(candidates,", "return max(list(candidates)[::-1],",
      "the last on a tie"),
    M("settles", "inverted", 'check.verdict == "likely correct"',
      'check.verdict != "likely correct"', "all but a likely correct pose settle"),
    M("may_compete", "inverted", 'check.verdict == "uncertain"', 'check.verdict != "uncertain"',
      "all but an uncertain pose compete"),
    M("only_free", "inverted", 'return check.rule == "free"', 'return check.rule != "free"',
      "every pose but a free one competes"),
    M("covers_more", "inverted", ".min() >= gain)", ".min() < gain)",
      "a slid start that covers less is kept"),
    M("covers_more", "either-cloud", ".min() >= gain)", ".max() >= gain)",
      "covering more of one cloud is enough"),
    M("displaces", "inverted", "verdict_rank(check) > (", "verdict_rank(check) < (",
      "a worse pose displaces"),
    M("displaces", "no-head-start", "held.overlap_fit + margin", "held.overlap_fit",
      "no margin: any higher overlap fit displaces"),
    M("ranks_higher", "inverted", "verdict_rank(check) > verdict_rank(held)",
      "verdict_rank(check) < verdict_rank(held)", "the lower rank wins"),
    M("ranks_higher", "tie-wins", "verdict_rank(check) > verdict_rank(held)",
      "verdict_rank(check) >= verdict_rank(held)", "a tie wins"),
    M("settled_better", "inverted", "return not settles(held) and better_verdict(",
      "return not settles(held) and not better_verdict(", "a worse refined answer replaces"),
    M("settled_better", "replaces-likely-correct", "return not settles(held) and",
      "return", "a likely correct answer is replaced"),
    M("better_verdict", "inverted", "verdict_rank(check)[0] > verdict_rank(held)[0]",
      "verdict_rank(check)[0] < verdict_rank(held)[0]", "the worse verdict wins"),
    M("better_verdict", "overlap-counts", "verdict_rank(check)[0] > verdict_rank(held)[0]",
      "verdict_rank(check) > verdict_rank(held)", "a higher overlap fit wins too"),
    M("partial_overlap", "inverted", "return fitness is None or fitness < level",
      "return not (fitness is None or fitness < level)", "partial where the fast path fits"),
    M("partial_overlap", "none-whole", "fitness is None or", "fitness is not None and",
      "no fast path run: not partial"),
    # --- One pose per basin
    M("apart", "inverted", "rotation_between_deg(a, b) >= degrees",
      "rotation_between_deg(a, b) < degrees", "near poses are apart"),
    M("in_basin_of", "inverted", "o.pose) < degrees", "o.pose) >= degrees",
      "in the basin of any pose far from it"),
    M("in_basin_of", "all", "return any(", "return all(", "must be near every other"),
    M("one_per_basin", "keeps-all", "if all(", "if True or all(", "no basin merges"),
    M("one_per_basin", "turn-and-shift", ">= degrees\n            or np.linalg",
      ">= degrees\n            and np.linalg", "distinct only if both turned and moved"),
    M("one_per_basin", "no-count", "if len(out) == count:", "if False:", "the count ignored"),
    M("same_place", "inverted", "return rotation_between_deg(a, b) < degrees and shift < reach",
      "return not (rotation_between_deg(a, b) < degrees and shift < reach)",
      "different places are one"),
    M("same_place", "turn-or-shift", "and shift < reach", "or shift < reach",
      "one place if either the turn or the shift is small"),
    M("most_matched", "fewest", "np.argmax(counts[open_])", "np.argmin(counts[open_])",
      "fewest matches first"),
    M("most_matched", "no-basin", "open_ &= ~((turn < degrees) & near_pose)",
      "open_[i] = False", "poses in one basin all kept"),
    M("most_agreed", "least", "agree.sum(1).argmax()", "agree.sum(1).argmin()",
      "the pose fewest matches agree with"),
    M("most_agreed", "last-on-tie", "int(agree.sum(1).argmax())",
      "int(len(agree) - 1 - agree.sum(1)[::-1].argmax())", "the last on a tie"),
    # --- The scene search's trimmed fit
    M("lowest", "highest", "np.argsort(fits,", "np.argsort(-fits,", "the highest fits"),
    M("lowest", "equals-reversed", 'np.argsort(fits, kind="stable")[:count]',
      '(len(fits) - 1 - np.argsort(fits[::-1], kind="stable"))[:count]',
      "equals in reverse order"),
    M("lowest_quarter", "at-most", "max(len(fits) // 4, at_least)",
      "min(len(fits) // 4, at_least)", "at most, not at least, ``at_least``"),
    M("lowest_quarter", "keeps-all", "max(len(fits) // 4, at_least)", "len(fits)",
      "nothing dropped"),
    M("best_quarter", "last-quarter", "list(ordered[:", "list(ordered[::-1][:",
      "the worst quarter"),
    M("best_quarter", "at-most", "max(len(ordered) // 4", "min(len(ordered) // 4",
      "at most, not at least, ``at_least``"),
    M("least_first", "most-first", "key=lambda item: item[0])",
      "key=lambda item: item[0], reverse=True)", "the largest fit first"),
    M("least_trimmed", "most", "min(refined,", "max(refined,", "the largest fit wins"),
    M("polished", "inverted", "if fit < best_fit:", "if fit > best_fit:",
      "only a fit above infinity wins: always the fallback"),
    M("polished", "last-on-tie", "if fit < best_fit:", "if fit <= best_fit:",
      "the last on a tie"),
)
# fmt: on
del M


def functions(source: str) -> dict[str, tuple[int, int]]:
    """The top-level functions of ``source``: name -> (first line, last line), 1-based,
    decorators and docstring included."""
    spans = {}
    for node in ast.parse(source).body:
        if isinstance(node, ast.FunctionDef):
            first = min([node.lineno] + [d.lineno for d in node.decorator_list])
            spans[node.name] = (first, node.end_lineno)
    return spans


def apply(source: str, mutant: Mutant) -> str:
    """``source`` with ``mutant`` applied inside its rule's function; MaskNetError where
    the function is missing or ``mutant.old`` does not occur in it exactly once."""
    span = functions(source).get(mutant.rule)
    if span is None:
        raise MaskNetError(f"{mutant.name}: no function {mutant.rule} in the arbiter")
    lines = source.splitlines(keepends=True)
    body = "".join(lines[span[0] - 1 : span[1]])
    found = body.count(mutant.old)
    if found != 1:
        raise MaskNetError(f"{mutant.name}: {mutant.old!r} occurs {found} times in {mutant.rule}")
    changed = "".join(lines[: span[0] - 1]) + body.replace(mutant.old, mutant.new)
    changed += "".join(lines[span[1] :])
    ast.parse(changed)  # a mutant must still compile
    return changed


def unmutated_rules(source: str, mutants: tuple[Mutant, ...] = MUTANTS) -> list[str]:
    """The rule functions of ``source`` (public top-level functions) no mutant changes."""
    covered = {m.rule for m in mutants}
    return sorted(n for n in functions(source) if not n.startswith("_") and n not in covered)


def run_tests(src: Path, tests: list[str], timeout: float) -> tuple[str, str, float]:
    """Run ``pytest -x`` over ``tests`` with ``src`` first on the path: (outcome, first
    failing test id or "", seconds). outcome: passed, failed, timeout or error."""
    env = dict(os.environ, PYTHONPATH=str(src), PYTHONDONTWRITEBYTECODE="1")
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests]
    start = time.perf_counter()
    try:
        run = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True,
                             timeout=timeout)  # fmt: skip
    except subprocess.TimeoutExpired:
        return "timeout", "", time.perf_counter() - start
    seconds = time.perf_counter() - start
    failing = re.search(r"^(?:FAILED|ERROR) (\S+)", run.stdout, re.M)
    if run.returncode == 0:
        return "passed", "", seconds
    if failing:
        return "failed", failing.group(1), seconds
    last = (run.stdout.strip() or run.stderr.strip() or "no output").splitlines()[-1]
    return "error", last, seconds


def imported_from(src: Path) -> str:
    """Where the arbiter is imported from with ``src`` first on the path."""
    code = "import masknet.registration.judge.arbiter as a; print(a.__file__)"
    env = dict(os.environ, PYTHONPATH=str(src), PYTHONDONTWRITEBYTECODE="1")
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    return run.stdout.strip()


def verdict(mutant: Mutant, outcome: str) -> str:
    """caught (a test failed, or the run hung), equivalent (survived, with a reason) or
    survived."""
    if outcome in ("failed", "timeout"):
        return "caught"
    if outcome == "passed":
        return "equivalent" if mutant.equivalent else "survived"
    return "error"


def run_pass(mutants: list[Mutant], tests: list[str], timeout: float) -> dict:
    """Apply each of ``mutants`` to a copy of src/ and run ``tests``; the record of the pass."""
    original = (ROOT / "src" / ARBITER).read_text()
    for mutant in mutants:  # all texts found before any test runs
        apply(original, mutant)
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="mutate_arbiter_") as tmp:
        src = Path(tmp) / "src"
        shutil.copytree(ROOT / "src", src, ignore=shutil.ignore_patterns("__pycache__"))
        if not imported_from(src).startswith(str(src)):
            raise MaskNetError(f"the copy under {src} is not what Python imports")
        outcome, first, seconds = run_tests(src, tests, timeout)
        print(f"unmutated: {outcome} in {seconds:.1f} s", flush=True)
        if outcome != "passed":
            raise MaskNetError(f"the unmutated tests do not pass ({outcome} {first})")
        records = []
        for mutant in mutants:
            (src / ARBITER).write_text(apply(original, mutant))
            outcome, first, took = run_tests(src, tests, timeout)
            records.append(dict(mutant=mutant.name, rule=mutant.rule, does=mutant.does,
                                old=mutant.old, new=mutant.new, result=verdict(mutant, outcome),
                                caught_by=first, equivalent=mutant.equivalent,
                                seconds=round(took, 1)))  # fmt: skip
            print(f"{mutant.name}: {records[-1]['result']} {first} ({took:.1f} s)", flush=True)
        (src / ARBITER).write_text(original)
    return {
        "command": "python scripts/mutate_arbiter.py " + " ".join(sys.argv[1:]),
        "tests": tests,
        "machine": machine(),
        "unmutated_seconds": round(seconds, 1),
        "wall_seconds": round(time.perf_counter() - start, 1),
        "mutants": records,
    }


def machine() -> str:
    """The CPU (its model name where Linux gives one), its cores and the Python."""
    cpuinfo = Path("/proc/cpuinfo")
    text = cpuinfo.read_text() if cpuinfo.exists() else ""
    model = re.search(r"^model name\s*:\s*(.+)$", text, re.M)
    name = model.group(1).strip() if model else platform.machine()
    return f"{name}, {os.cpu_count()} CPUs, Python {platform.python_version()}"


def table(report: dict) -> str:
    """The pass as a markdown table: mutant, what it does, caught by."""
    counts = {k: sum(r["result"] == k for r in report["mutants"]) for k in
              ("caught", "survived", "equivalent", "error")}  # fmt: skip
    lines = [
        "# Mutation pass over the arbiter",
        "",
        f"`{report['command']}` over `{' '.join(report['tests'])}` ({report['machine']}):",
        f"{len(report['mutants'])} mutants, "
        + ", ".join(f"{n} {k}" for k, n in counts.items() if n)
        + f"; {report['wall_seconds']:.0f} s in all (the unmutated tests "
        f"{report['unmutated_seconds']:.0f} s).",
        "",
        "| mutant | what it does | caught by |",
        "|---|---|---|",
    ]
    for r in report["mutants"]:
        by = f"`{r['caught_by']}`" if r["caught_by"] else r["result"].upper()
        if r["result"] == "equivalent":
            by = f"equivalent: {r['equivalent']}"
        lines.append(f"| `{r['mutant']}` | {r['does']} | {by} |")
    return "\n".join(lines) + "\n"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", action="append", default=[],
                   help="a rule (fits_better) or a mutant (fits_better/inverted); repeatable")  # fmt: skip
    p.add_argument("--tests", nargs="+", default=list(TESTS), help="pytest paths, in order")
    p.add_argument("--timeout", type=float, default=900.0, help="seconds per mutant's run")
    p.add_argument("-o", "--out", help="folder for mutants.json and mutants.md")
    p.add_argument("--list", action="store_true", help="list the mutants and stop")
    args, pytest_args = p.parse_known_args()  # other options go to pytest (-k, --ignore)
    mutants = [m for m in MUTANTS if not args.only or {m.rule, m.name} & set(args.only)]
    if not mutants:
        raise MaskNetError(f"no mutant matches {args.only}")
    if args.list:
        print("\n".join(f"{m.name}: {m.does}" for m in mutants))
        return 0
    report = run_pass(mutants, args.tests + pytest_args, args.timeout)
    print(table(report))
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "mutants.json").write_text(json.dumps(report, indent=1) + "\n")
        (out / "mutants.md").write_text(table(report))
    return int(any(r["result"] in ("survived", "error") for r in report["mutants"]))


if __name__ == "__main__":
    run_script(main)

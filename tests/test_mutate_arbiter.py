"""scripts/mutate_arbiter.py: its table of mutants still applies to the arbiter as it is,
so that the mutation pass (slow, not part of the test run) cannot rot into testing
nothing. The pass itself: docs/results/arbiter_mutants/."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from masknet.errors import MaskNetError

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location(
    "mutate_arbiter", ROOT / "scripts" / "mutate_arbiter.py"
)
mutate = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(mutate)
SOURCE = (ROOT / "src" / mutate.ARBITER).read_text()


@pytest.mark.parametrize("mutant", mutate.MUTANTS, ids=lambda m: m.name)
def test_each_mutant_finds_its_text_once_and_changes_only_its_rule(mutant):
    changed = mutate.apply(SOURCE, mutant)
    assert changed != SOURCE
    before, after = mutate.functions(SOURCE), mutate.functions(changed)
    assert before.keys() == after.keys()
    old, new = SOURCE.splitlines(), changed.splitlines()
    differing = [i + 1 for i, (a, b) in enumerate(zip(old, new, strict=True)) if a != b]
    first, last = before[mutant.rule]
    assert differing and all(first <= line <= last for line in differing)


def test_every_rule_of_the_arbiter_has_a_mutant_and_every_name_is_one():
    assert mutate.unmutated_rules(SOURCE) == []
    names = [m.name for m in mutate.MUTANTS]
    assert len(names) == len(set(names))


def test_a_mutant_whose_text_is_gone_stops_the_pass():
    gone = mutate.Mutant("fits_better", "gone", "candidate.score >> score", "x", "nothing")
    with pytest.raises(MaskNetError, match="occurs 0 times in fits_better"):
        mutate.apply(SOURCE, gone)
    # the text of another rule does not count
    elsewhere = gone._replace(old="return fitness >= level")
    with pytest.raises(MaskNetError, match="occurs 0 times"):
        mutate.apply(SOURCE, elsewhere)
    with pytest.raises(MaskNetError, match="no function nowhere"):
        mutate.apply(SOURCE, gone._replace(rule="nowhere"))


def test_unmutated_rules_names_a_rule_left_out():
    kept = tuple(m for m in mutate.MUTANTS if m.rule != "polished")
    assert mutate.unmutated_rules(SOURCE, kept) == ["polished"]

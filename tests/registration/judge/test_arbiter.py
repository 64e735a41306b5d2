"""masknet.registration.judge.arbiter: each rule between poses on small hand-made candidates.

That no pose is compared with another anywhere else is tests/test_arbiter_rule.py's
``test_no_pose_is_compared_outside_the_arbiter``."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from masknet.registration.judge import arbiter
from masknet.registration.judge.arbiter import Candidate
from masknet.registration.judge.assessment import Assessment
from masknet.registration.judge.fit import FIT_SLACK, PoseFit


def _pose(degrees: float, shift: float = 0.0) -> np.ndarray:
    """(4, 4): turned ``degrees`` about z, moved ``shift`` along x."""
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("z", degrees, degrees=True).as_matrix()
    pose[0, 3] = shift
    return pose


def _cand(
    score: float, degrees: float = 0.0, stage: str = "", fitness: float = 1.0, rmse: float = 0.0
) -> Candidate:
    return Candidate(_pose(degrees), stage, PoseFit(fitness, rmse, score))


def _check(verdict: str, overlap_fit: float, rule: str = "") -> Assessment:
    return Assessment(verdict, "", overlap_fit, 0.0, 0.0, 0.0, 0.0, 1.0, rule=rule)


def _stages(candidates: list[Candidate]) -> list[str]:
    return [c.stage for c in candidates]


def test_a_candidate_reads_its_fit():
    c = Candidate(_pose(0), "fpfh", PoseFit(0.9, 0.01, 0.8))
    assert (c.fitness, c.rmse, c.score, c.kind, c.check) == (0.9, 0.01, 0.8, "fpfh", None)


# --- The pipelines' score -----------------------------------------------------------------


def test_rank_prefers_score_then_fitness_then_lower_rmse():
    a = _cand(0.50, stage="a", fitness=0.9, rmse=0.02)
    b = _cand(0.50, stage="b", fitness=0.8, rmse=0.01)
    c = _cand(0.50, stage="c", fitness=0.8, rmse=0.03)
    d = _cand(0.60, stage="d", fitness=0.1, rmse=0.09)
    assert _stages(arbiter.best_first([c, b, a, d])) == ["d", "a", "b", "c"]


def test_best_first_keeps_the_order_of_equals_and_takes_a_key():
    entries = [_cand(0.5, stage="first"), _cand(0.5, stage="second"), _cand(0.1, stage="low")]
    assert _stages(arbiter.best_first(entries)) == ["first", "second", "low"]
    by_stage = arbiter.best_first(entries, key=lambda c: c.stage)
    assert _stages(by_stage) == ["second", "low", "first"]


def test_best_score_is_the_highest():
    assert arbiter.best_score([_cand(0.3), _cand(0.7), _cand(0.5)]) == 0.7


def test_fits_better_needs_a_strictly_higher_score():
    assert arbiter.fits_better(_cand(0.81), 0.80)
    assert not arbiter.fits_better(_cand(0.80), 0.80)  # a tie keeps the held answer
    assert not arbiter.fits_better(_cand(0.79, fitness=1.0), 0.80)


def test_within_gap_includes_its_bound():
    assert arbiter.within_gap(0.75, 1.0, 0.25)
    assert not arbiter.within_gap(0.74, 1.0, 0.25)
    assert arbiter.within_gap(1.2, 1.0, 0.0)


def test_alike_keeps_those_within_the_margin_of_the_first():
    ordered = [_cand(0.9, stage="a"), _cand(0.89, stage="b"), _cand(0.8, stage="c")]
    assert _stages(arbiter.alike(ordered, 0.02)) == ["a", "b"]
    reached = {"a": 0.5, "b": 0.3, "c": 0.49}  # measured against the first, as ordered
    assert _stages(arbiter.alike(ordered, 0.02, key=lambda c: reached[c.stage])) == ["a", "c"]


def test_the_least_turned_wins_and_the_first_on_a_tie():
    entries = [_cand(1, 40, "far"), _cand(1, -5, "near"), _cand(1, 5, "near too")]
    assert arbiter.least_turned(entries).stage == "near"


def test_the_runner_up_is_the_first_pose_apart_however_it_fits():
    winner = _cand(0.9, 0, "winner")
    ordered = [winner, _cand(0.9, 3, "same basin"), _cand(0.1, 30, "far"), _cand(0.8, 60, "b")]
    assert arbiter.runner_up(winner, ordered, 10.0).stage == "far"
    assert arbiter.runner_up(winner, ordered[:2], 10.0) is None


def test_a_close_rival_must_be_apart_and_within_the_margin():
    held = _cand(0.90, 0, "fast")
    beyond, close = _cand(0.80, 30, "search"), _cand(0.89, 60, "runner-up")
    near = _cand(0.95, 3, "same basin")
    assert arbiter.close_rival(held, [near, beyond, close], 10.0, 0.02).stage == "runner-up"
    assert arbiter.close_rival(held, [near, beyond], 10.0, 0.02) is None
    # The search's rule would name the first pose apart, and call the choice clear.
    assert arbiter.runner_up(held, [near, beyond, close], 10.0).stage == "search"


def _no_refinement(c: Candidate) -> float:
    raise AssertionError("refined although no two answers fit alike")


def test_the_search_chooses_the_best_when_none_fits_alike():
    finals = [_cand(0.7, 60, "b"), _cand(0.9, 30, "a")]
    winner, rival, ambiguous = arbiter.search_choice(finals, 0.02, 10.0, 0.1, _no_refinement)
    assert (winner.stage, rival.stage, ambiguous) == ("a", "b", False)


def test_answers_that_met_in_one_basin_are_one_answer():
    """Two refined answers a degree apart fit alike, but are one: nothing to re-refine."""
    finals = [_cand(0.90, 30, "a"), _cand(0.899, 31, "its twin"), _cand(0.80, 5, "b")]
    winner, rival, ambiguous = arbiter.search_choice(finals, 0.02, 10.0, 0.1, _no_refinement)
    assert (winner.stage, rival.stage, ambiguous) == ("a", "b", False)


def test_the_search_merges_one_basin_then_prefers_the_least_turned_alike():
    finals = [_cand(0.90, 30, "turned"), _cand(0.905, 31, "its twin"), _cand(0.89, 5, "near")]
    reached = {"its twin": 0.95, "near": 0.94, "turned": 0.0}
    winner, rival, ambiguous = arbiter.search_choice(
        finals, 0.02, 10.0, 0.1, lambda c: reached[c.stage]
    )
    assert (winner.stage, rival.stage, ambiguous) == ("near", "its twin", True)


def test_the_refined_fits_part_answers_that_fit_alike():
    finals = [_cand(0.90, 30, "turned"), _cand(0.89, 5, "near")]
    reached = {"turned": 0.95, "near": 0.80}
    winner, rival, ambiguous = arbiter.search_choice(
        finals, 0.02, 10.0, 0.1, lambda c: reached[c.stage]
    )
    assert (winner.stage, rival.stage, ambiguous) == ("turned", "near", False)


# --- Early exits and guards -----------------------------------------------------------------


def test_accepts_at_the_level_and_above():
    assert arbiter.accepts(0.99, 0.99)
    assert not arbiter.accepts(0.9899, 0.99)


def test_the_search_exits_on_its_best_fit():
    fits = [PoseFit(0.5, 0.0, 0.5), PoseFit(0.995, 0.0, 0.6)]
    assert arbiter.exits(fits, 0.99)
    assert not arbiter.exits(fits[:1], 0.99)


def test_the_guard_allows_fit_slack():
    assert not arbiter.fits_worse(0.90 - FIT_SLACK / 2, 0.90)
    assert arbiter.fits_worse(0.90 - 2 * FIT_SLACK, 0.90)
    np.testing.assert_array_equal(
        arbiter.fits_worse(np.array([0.5, 0.89]), np.array([0.9, 0.9])), [True, False]
    )


# --- The verdict ------------------------------------------------------------------------


def test_verdicts_rank_before_overlap_fits():
    ranked = sorted(
        [_check("likely wrong", 0.9), _check("uncertain", 0.5), _check("likely correct", 0.6)],
        key=arbiter.verdict_rank,
        reverse=True,
    )
    assert [c.verdict for c in ranked] == ["likely correct", "uncertain", "likely wrong"]
    assert arbiter.verdict_rank(_check("uncertain", 0.7)) > arbiter.verdict_rank(
        _check("uncertain", 0.5)
    )


def test_the_best_judged_wins_by_verdict_then_overlap_fit_the_first_on_a_tie():
    """``best_judged`` reads each entry's verdict through ``check``; it takes any iterable."""
    checks = {
        "wrong": _check("likely wrong", 0.99),
        "unsure": _check("uncertain", 0.70),
        "unsure, closer": _check("uncertain", 0.75),
        "unsure, closer too": _check("uncertain", 0.75),
    }
    assert arbiter.best_judged(iter(checks), checks.__getitem__) == "unsure, closer"
    checks["right"] = _check("likely correct", 0.50)
    assert arbiter.best_judged(checks, checks.__getitem__) == "right"
    assert arbiter.best_judged(["wrong"], checks.__getitem__) == "wrong"


def test_only_a_likely_correct_pose_settles_and_only_an_uncertain_one_competes():
    assert arbiter.settles(_check("likely correct", 0.6))
    assert not arbiter.settles(_check("uncertain", 0.99))
    assert arbiter.may_compete(_check("uncertain", 0.5))
    assert not arbiter.may_compete(_check("likely wrong", 0.9))
    assert not arbiter.may_compete(_check("likely correct", 0.9))


def test_only_a_pose_whose_one_fault_is_freedom_competes_on_every_route():
    assert arbiter.only_free(_check("uncertain", 0.99, "free"))
    assert not arbiter.only_free(_check("uncertain", 0.99, "between"))
    assert not arbiter.only_free(_check("likely wrong", 0.99, "slid"))
    assert not arbiter.only_free(_check("likely correct", 0.99, "correct"))


def test_a_pose_displaces_by_verdict_or_by_more_than_the_margin():
    held = _check("uncertain", 0.80)
    assert arbiter.displaces(_check("likely correct", 0.60), held, 0.02)
    assert not arbiter.displaces(_check("likely wrong", 0.99), held, 0.02)
    assert not arbiter.displaces(_check("uncertain", 0.81), held, 0.02)  # within the margin
    assert arbiter.displaces(_check("uncertain", 0.85), held, 0.02)


def test_ranks_higher_has_no_head_start():
    held = _check("uncertain", 0.80)
    assert arbiter.ranks_higher(_check("uncertain", 0.81), held)
    assert not arbiter.ranks_higher(_check("uncertain", 0.80), held)
    assert arbiter.ranks_higher(_check("likely correct", 0.6), held)
    assert not arbiter.ranks_higher(_check("likely wrong", 0.99), held)


# --- One pose per basin -------------------------------------------------------------------


def test_apart_turns_at_least_the_degrees_whatever_the_shift():
    assert arbiter.apart(_pose(0), _pose(10.5), 10.0)
    assert not arbiter.apart(_pose(0), _pose(9.9, 5.0), 10.0)


def test_in_basin_of_any():
    others = [_cand(1, 40), _cand(1, 3)]
    assert arbiter.in_basin_of(_pose(0), others, 10.0)
    assert not arbiter.in_basin_of(_pose(0), others[:1], 10.0)


def test_one_per_basin_keeps_the_first_of_each():
    scored = [
        Candidate(_pose(0), "best", PoseFit(1, 0, 1)),
        Candidate(_pose(1), "same basin", PoseFit(1, 0, 1)),  # 1 degree, same place
        Candidate(_pose(1, 0.5), "moved", PoseFit(1, 0, 1)),  # 1 degree but 0.5 away
        Candidate(_pose(30), "turned", PoseFit(1, 0, 1)),
    ]
    kept = arbiter.one_per_basin(scored, count=5, limit=0.2, degrees=2.0)
    assert _stages(kept) == ["best", "moved", "turned"]
    assert _stages(arbiter.one_per_basin(scored, count=2, limit=0.2)) == ["best", "moved"]


def test_same_place_needs_both_the_turn_and_the_shift_of_the_centre():
    centre = np.array([1.0, 0.0, 0.0])
    assert arbiter.same_place(_pose(0), _pose(5, 0.05), centre, 10.0, 0.2)
    assert not arbiter.same_place(_pose(0), _pose(5, 0.5), centre, 10.0, 0.2)
    assert not arbiter.same_place(_pose(0), _pose(20), centre * 0, 10.0, 0.2)


def test_most_matched_takes_the_most_matches_one_per_basin():
    poses = np.stack([_pose(0), _pose(2, 0.01), _pose(90), _pose(0, 5.0)])
    counts = np.array([10, 30, 20, 5])
    assert arbiter.most_matched(poses, counts, 3, 10.0, 0.1) == [1, 2, 3]
    assert arbiter.most_matched(poses, counts, 2, 10.0, 0.1) == [1, 2]


def test_most_agreed_is_the_row_most_matches_agree_with_the_first_on_a_tie():
    agree = np.array([[1, 0, 0], [1, 1, 0], [0, 1, 1]], bool)
    assert arbiter.most_agreed(agree) == 1


# --- The scene search's trimmed fit ---------------------------------------------------------


def test_lowest_and_the_quarters():
    fits = np.array([0.5, 0.1, 0.3, 0.1, 0.9, 0.2, 0.7, 0.4])
    np.testing.assert_array_equal(arbiter.lowest(fits, 3), [1, 3, 5])
    np.testing.assert_array_equal(arbiter.lowest_quarter(fits, 1), [1, 3])
    np.testing.assert_array_equal(arbiter.lowest_quarter(fits, 3), [1, 3, 5])
    assert arbiter.best_quarter(list("abcdefgh")) == ["a", "b"]
    assert arbiter.best_quarter(list("abc")) == ["a"]
    assert arbiter.best_quarter(list("abcdefgh"), 3) == ["a", "b", "c"]


def test_least_trimmed_and_the_polish_pick_the_least_fit():
    a, b, c = _pose(0), _pose(10), _pose(20)
    refined = [(0.3, a), (0.1, b), (0.1, c)]
    assert [f for f, _ in arbiter.least_first(refined)] == [0.1, 0.1, 0.3]
    assert arbiter.least_first(refined)[0][1] is b
    assert arbiter.least_trimmed(refined) is b
    assert arbiter.polished(refined, c) is b


def test_the_polish_falls_back_where_no_fit_is_finite():
    a, fallback = _pose(10), _pose(0)
    assert arbiter.polished([(np.inf, a)], fallback) is fallback
    assert arbiter.least_trimmed([(np.inf, a)]) is a  # the refinement's rule takes it


@pytest.mark.parametrize(
    ("old", "name"),
    [
        ("masknet.registration.judge.fit", "fits_worse"),
        ("masknet.registration.stages.consensus", "verdict_rank"),
    ],
)
def test_the_old_homes_of_the_rules_still_answer(old, name):
    import importlib

    with pytest.warns(DeprecationWarning, match=f"arbiter.{name}"):
        assert getattr(importlib.import_module(old), name) is getattr(arbiter, name)


def test_a_better_verdict_wins_whatever_the_overlap_fits():
    """``better_verdict``: the verdict alone; a higher overlap fit of the same verdict
    does not win (where ``ranks_higher`` lets it)."""
    right, unsure = _check("likely correct", 0.5), _check("uncertain", 0.99)
    assert arbiter.better_verdict(right, unsure) and not arbiter.better_verdict(unsure, right)
    same_higher = _check("likely correct", 0.9)
    assert not arbiter.better_verdict(same_higher, right)
    assert arbiter.ranks_higher(same_higher, right)


def test_a_settled_answer_needs_a_better_verdict_and_a_held_one_not_likely_correct():
    """``settled_better``: the search's refined answer replaces an ``uncertain`` one where
    its verdict is better; a ``likely correct`` answer is kept, and the refined pose is then
    not judged at all."""
    asked = []

    def judged(verdict: str, overlap_fit: float):
        def check():
            asked.append(verdict)
            return _check(verdict, overlap_fit)

        return check

    unsure = _check("uncertain", 0.9)
    assert arbiter.settled_better(judged("likely correct", 0.7), unsure)
    assert not arbiter.settled_better(judged("uncertain", 0.99), unsure)  # same verdict
    assert not arbiter.settled_better(judged("likely wrong", 0.99), unsure)
    asked.clear()
    assert not arbiter.settled_better(judged("likely correct", 0.99), _check("likely correct", 0.6))
    assert asked == []  # a likely correct answer: its refined pose is not judged


def test_partial_overlap_by_the_fast_paths_fit():
    """Under the level (or no fast path run): both clouds partial."""
    assert arbiter.partial_overlap(0.3, 0.8) and arbiter.partial_overlap(None, 0.8)
    assert not arbiter.partial_overlap(0.96, 0.8) and not arbiter.partial_overlap(0.8, 0.8)


def test_covers_more_needs_the_gain_on_each_cloud():
    """``covers_more``: at least the gain more of the source and of the template; more of
    one cloud does not make up for less of the other."""
    held = np.array([0.75, 0.5])  # binary fractions: the bound is exact
    assert arbiter.covers_more(np.array([0.9, 0.7]), held, 0.0625)
    assert arbiter.covers_more(np.array([0.8125, 0.5625]), held, 0.0625)  # the bound itself
    assert not arbiter.covers_more(np.array([1.0, 0.5]), held, 0.0625)
    assert not arbiter.covers_more(np.array([0.78, 0.9]), held, 0.0625)
    assert not arbiter.covers_more(held, held, 0.0625)

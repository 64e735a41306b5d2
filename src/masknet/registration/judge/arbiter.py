"""The arbiter: every rule by which ``auto``, ``robust`` and the scene search decide between
poses, and the one type of a pose on its way to an answer (:class:`Candidate`).

The stages find poses; the arbiter says which one wins, which is the runner-up, whether
the answer is ambiguous, when a search may stop, and which poses are one basin. Each rule
is a small function here, named for what it decides, and takes its thresholds from the
caller (the fields of :class:`~masknet.registration.terms.options.RobustOptions`, the module
constants beside the stage that measured them): the arbiter invents none.

The measures it compares (one per stage, not yet one for all):

* the pipelines' truncated **score** (:class:`~masknet.registration.judge.fit.PoseFit`, higher
  is better; ties by fitness, then the lower RMSE), with its **fitness** for the early
  exits;
* the **verdict** (:class:`~masknet.registration.judge.assessment.Assessment`: its rank, then
  the overlap fit);
* the scene search's **trimmed fit** (mean squared distance of the best share, lower is
  better);
* RANSAC's **consensus** (how many matches a pose brings within its threshold).

Where two stages decide alike in words but not to the letter, both rules stand here under
their own names (:func:`displaces` and :func:`ranks_higher`, :func:`runner_up` and
:func:`close_rival`, :func:`least_trimmed` and :func:`polished`): folding one into the
other would move results.

Example::

    fast = Candidate(pose, "fast", pose_fit(tree, points, pose, limit))
    if fits_better(fast, searched.score): ...
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING, Any, NamedTuple, TypeVar

import numpy as np

from masknet.geometry.se3 import rotation_angle_deg, transform_points
from masknet.registration.judge.fit import FIT_SLACK
from masknet.registration.judge.hypotheses import rotation_between_deg

if TYPE_CHECKING:
    from masknet.registration.judge.assessment import Assessment
    from masknet.registration.judge.fit import PoseFit

__all__ = [
    "Candidate",
    "accepts",
    "alike",
    "apart",
    "best_first",
    "best_judged",
    "best_quarter",
    "best_score",
    "covers_more",
    "close_rival",
    "displaces",
    "exits",
    "fits_better",
    "fits_worse",
    "in_basin_of",
    "least_first",
    "least_trimmed",
    "least_turned",
    "lowest",
    "lowest_quarter",
    "may_compete",
    "most_agreed",
    "most_matched",
    "only_free",
    "one_per_basin",
    "polished",
    "rank",
    "ranks_higher",
    "runner_up",
    "same_place",
    "search_choice",
    "settles",
    "verdict_rank",
    "within_gap",
]

T = TypeVar("T")


class Candidate(NamedTuple):
    """A pose on its way to an answer.

    pose: (4, 4) source -> template. stage: where it came from (``"fpfh"``,
    ``"fpfh-masked"``, ``"rotation"``, ``"as given"``, ``"identity"``: the search's
    hypotheses; ``"fast"``, ``"search"``, ``"runner-up"``: ``auto``'s answers;
    ``"ransac"``, ``"start"``: the consensus front end's). fit: its
    :class:`~masknet.registration.judge.fit.PoseFit` on the prepared pair, or None where the
    stage does not score it. check: its verdict
    (:class:`~masknet.registration.judge.assessment.Assessment`) once judged, else None."""

    pose: np.ndarray
    stage: str
    fit: PoseFit | None = None
    check: Assessment | None = None

    @property
    def score(self) -> float:
        """The fit's truncated score (0-1, higher is better)."""
        return self.fit.score

    @property
    def fitness(self) -> float:
        """The fit's share of points within the inlier distance."""
        return self.fit.fitness

    @property
    def rmse(self) -> float:
        """The fit's RMS distance of those points, input units."""
        return self.fit.rmse

    @property
    def kind(self) -> str:
        """The former name of ``stage`` (a ``Scored`` hypothesis's)."""
        return self.stage


# --- The pipelines' score ----------------------------------------------------------------


def rank(candidate: Candidate) -> tuple[float, float, float]:
    """A sort key of a scored candidate: higher score first, then fitness, then lower RMSE."""
    return candidate.score, candidate.fitness, -candidate.rmse


def best_first(candidates: Sequence[T], key: Callable[[T], Any] = rank) -> list[T]:
    """``candidates`` best first by ``key`` (default :func:`rank`); equals keep their order."""
    return sorted(candidates, key=key, reverse=True)


def best_score(candidates: Sequence[Candidate]) -> float:
    """The highest score among ``candidates`` (at least one)."""
    return max(c.score for c in candidates)


def fits_better(candidate: Candidate, score: float) -> bool:
    """Whether ``candidate`` displaces a held answer of ``score``: a strictly higher score
    (a tie keeps the held answer). Not :func:`rank`: fitness and RMSE break no tie here."""
    return candidate.score > score


def within_gap(score: float, best: float, gap: float) -> bool:
    """Whether a ``score`` lies within ``gap`` of the ``best`` (at most that far below)."""
    return score >= best - gap


def alike(
    ordered: Sequence[T], margin: float, key: Callable[[T], float] = lambda c: c.score
) -> list[T]:
    """The entries of ``ordered`` (best first by ``key``) within ``margin`` of the first:
    answers the measure cannot part."""
    return [c for c in ordered if within_gap(key(c), key(ordered[0]), margin)]


def least_turned(candidates: Sequence[Candidate]) -> Candidate:
    """The candidate whose pose turns least from the pose as given (the identity): where
    the data cannot choose, the input is the only other evidence. The first on a tie."""
    return min(candidates, key=lambda c: rotation_between_deg(c.pose, np.eye(4)))


def runner_up(winner: Candidate, ordered: Sequence[Candidate], degrees: float) -> Candidate | None:
    """The search's runner-up: the first of ``ordered`` (best first) other than
    ``winner`` whose pose lies ``degrees`` or more from it, however it fits; None if none."""
    return next(
        (c for c in ordered if c is not winner and apart(c.pose, winner.pose, degrees)), None
    )


def close_rival(
    held: Candidate, others: Sequence[Candidate], degrees: float, margin: float
) -> Candidate | None:
    """``auto``'s runner-up when the fast path's pose wins after all: the first of
    ``others`` (the search's answer, then its runner-up) ``degrees`` or more from ``held``
    that scores within ``margin`` of it; None if none (then the answer is not ambiguous).
    Unlike :func:`runner_up`, a pose apart but beyond the margin is passed over."""
    for other in others:
        if apart(other.pose, held.pose, degrees) and within_gap(other.score, held.score, margin):
            return other
    return None


def search_choice(
    finals: list[Candidate],
    margin: float,
    degrees: float,
    limit: float,
    refined_score: Callable[[Candidate], float],
) -> tuple[Candidate, Candidate | None, bool]:
    """The answer of the search among its refined ``finals`` (at least one), the runner-up
    and whether the choice is ambiguous.

    Answers that met in one basin (:func:`one_per_basin`, 2 degrees or ``limit``) are
    one. Where several fit within ``margin`` of the best (:func:`alike`), each is ranked
    instead by ``refined_score`` (its score refined as far as it goes) and those within
    ``margin`` of that best stay alike; among the alike :func:`least_turned` wins. The
    runner-up is :func:`runner_up` (``degrees`` away); the choice is ambiguous where it
    reaches within ``margin`` of the winner."""
    finals = one_per_basin(best_first(finals), len(finals), limit)
    alike_now = alike(finals, margin)
    reached = {id(f): f.score for f in finals}
    if len(alike_now) > 1:
        reached = {id(f): refined_score(f) for f in finals}
        finals = best_first(finals, key=lambda f: reached[id(f)])
        alike_now = alike(finals, margin, key=lambda f: reached[id(f)])
    winner = least_turned(alike_now)
    rival = runner_up(winner, finals, degrees)
    ambiguous = rival is not None and within_gap(reached[id(rival)], reached[id(winner)], margin)
    return winner, rival, ambiguous


# --- Early exits and guards --------------------------------------------------------------


def accepts(fitness: float, level: float) -> bool:
    """Whether a pose's ``fitness`` over the checked points ends the call: at least
    ``level`` (``accept_fitness``, ``object_accept_fitness``)."""
    return fitness >= level


def exits(fits: Sequence[PoseFit], level: float) -> bool:
    """The search's early exit: whether the best of ``fits`` (each pose's fit over the
    checked points) :func:`accepts` at ``level``."""
    return accepts(max(f.fitness for f in fits), level)


def fits_worse(new_score: Any, start_score: Any) -> Any:
    """The rounds' guard: whether a pose's score (:class:`~masknet.registration.judge.fit.PoseFit`)
    is more than ``FIT_SLACK`` below its start's, so that the round is undone; scalars or
    arrays alike."""
    return new_score < start_score - FIT_SLACK


# --- The verdict -------------------------------------------------------------------------


def verdict_rank(check: Assessment) -> tuple[int, float]:
    """A sort key: better verdicts first, then the larger overlap fit."""
    from masknet.registration.judge.assessment import VERDICTS

    return -VERDICTS.index(check.verdict), check.overlap_fit


def best_judged(candidates: Iterable[T], check: Callable[[T], Assessment]) -> T:
    """The candidate (at least one) whose verdict ``check(candidate)`` ranks best
    (:func:`verdict_rank`: the verdict, then the overlap fit); the first on a tie."""
    return max(candidates, key=lambda candidate: verdict_rank(check(candidate)))


def settles(check: Assessment) -> bool:
    """Whether a judged pose ends the call: ``likely correct``."""
    return check.verdict == "likely correct"


def may_compete(check: Assessment) -> bool:
    """Whether a pose the front end did not settle on still competes with the search's
    answer on scans: ``uncertain`` (a ``likely wrong`` one does not)."""
    return check.verdict == "uncertain"


def only_free(check: Assessment) -> bool:
    """Whether a judged pose's one fault is that the clouds leave it free (the verdict's
    rule ``free``: it fits as right poses do and no slide along its free motions fits
    better, but the fit does not pin it). The front end's such pose competes with any later
    answer, on every route (:func:`ranks_higher`): it does not end the call, since the
    slide search does not look along a free turn, but neither does a worse-fitting pose of
    the fast path or the search replace it."""
    return check.rule == "free"


def displaces(check: Assessment, held: Assessment, margin: float) -> bool:
    """Whether a pose judged ``check`` displaces one judged ``held`` (the consensus front
    end): a better verdict, or the same verdict and an overlap fit more than ``margin``
    higher. The head start keeps a tie from going either way with the last bits of
    Open3D's parallel sums (two calls on one scan-view pair ended 0.2 degrees apart), and
    keeps the pose nearer the start where a symmetric shape fits a flip as well."""
    return verdict_rank(check) > (verdict_rank(held)[0], held.overlap_fit + margin)


def ranks_higher(check: Assessment, held: Assessment) -> bool:
    """Whether ``check`` ranks strictly above ``held`` (:func:`verdict_rank`, no head
    start): on scans, an ``uncertain`` consensus against the search's answer. Unlike
    :func:`displaces`, any higher overlap fit of the same verdict wins."""
    return verdict_rank(check) > verdict_rank(held)


def covers_more(shares: np.ndarray, held: np.ndarray, gain: float) -> bool:
    """Whether a pose covering ``shares`` (2,) of the two clouds (each the share of its
    points within the inlier distance of the other) covers at least ``gain`` more of each
    than one covering ``held`` (2,): the consensus front end's start slid to cover more
    (``COVER_GAIN``), still covering more once refined."""
    return bool((np.asarray(shares) - np.asarray(held)).min() >= gain)


def better_verdict(check: Assessment, held: Assessment) -> bool:
    """Whether ``check``'s verdict is better than ``held``'s, whatever their overlap fits:
    ``auto``'s front end, run on a template measured as a scan once the fast path has not
    held, against the search's answer. There a thin object reads as one-sided, and the
    overlap fit preferred the front end's pose 4.7 degrees off to the search's 0.13 on a
    noisy ModelNet40 pair."""
    return verdict_rank(check)[0] > verdict_rank(held)[0]


def settled_better(check: Callable[[], Assessment], held: Assessment) -> bool:
    """Whether the search's answer refined from a looser cut-off, which fits better, replaces
    the answer judged ``held``: where its verdict (``check()``, asked only where ``held`` is
    not ``likely correct``) is better (:func:`better_verdict`). The one-way score alone
    preferred a pose slid 12 cm along a room's planes on the 3DMatch pair."""
    return not settles(held) and better_verdict(check(), held)


def partial_overlap(fitness: float | None, level: float) -> bool:
    """Whether the fast path's pose, fitting ``fitness`` of the source (None: it did not
    run), leaves the pair to a scan's front end (``auto``, a template measured as a scan
    once the fast path has not held): under ``level``
    (:attr:`~masknet.registration.judge.shape.ShapeTable.partial_fit`), both clouds
    partial; a part of a thin object near its pose fits more."""
    return fitness is None or fitness < level


# --- One pose per basin ------------------------------------------------------------------


def apart(a: np.ndarray, b: np.ndarray, degrees: float) -> bool:
    """Whether poses ``a`` and ``b`` (4, 4) turn ``degrees`` or more apart: different
    answers (``distinct_deg``), whatever their translations."""
    return rotation_between_deg(a, b) >= degrees


def in_basin_of(pose: np.ndarray, others: Sequence[Candidate], degrees: float) -> bool:
    """Whether ``pose`` (4, 4) turns less than ``degrees`` from any of ``others``."""
    return any(rotation_between_deg(pose, o.pose) < degrees for o in others)


def one_per_basin(
    ordered: Sequence[Candidate], count: int, limit: float, degrees: float = 2.0
) -> list[Candidate]:
    """The first ``count`` entries of ``ordered`` (best first) whose poses differ from
    every earlier one kept by ``degrees`` or ``limit`` of translation: the same basin
    once."""
    out: list[Candidate] = []
    for entry in ordered:
        if len(out) == count:
            break
        if all(
            rotation_between_deg(entry.pose, other.pose) >= degrees
            or np.linalg.norm(entry.pose[:3, 3] - other.pose[:3, 3]) >= limit
            for other in out
        ):
            out.append(entry)
    return out


def same_place(
    a: np.ndarray, b: np.ndarray, point: np.ndarray, degrees: float, reach: float
) -> bool:
    """Whether poses ``a`` and ``b`` (4, 4) are one answer of the consensus front end:
    turned less than ``degrees`` apart, and moving ``point`` (3,) (the source's centre) to
    places less than ``reach`` apart (one voxel)."""
    shift = np.linalg.norm(transform_points(a, point) - transform_points(b, point))
    return rotation_between_deg(a, b) < degrees and shift < reach


def most_matched(
    poses: np.ndarray, counts: np.ndarray, keep: int, degrees: float, reach: float
) -> list[int]:
    """RANSAC's best distinct poses: indices of ``poses`` (H, 4, 4), most matches
    (``counts`` (H,)) first, each not within ``degrees`` and ``reach`` of translation of
    one already chosen, at most ``keep`` (greedy, vectorised over all poses)."""
    open_ = np.ones(len(poses), bool)
    chosen: list[int] = []
    while len(chosen) < keep and open_.any():
        i = int(np.flatnonzero(open_)[np.argmax(counts[open_])])
        chosen.append(i)
        turn = rotation_angle_deg(poses[:, :3, :3] @ poses[i, :3, :3].T)
        near_pose = np.linalg.norm(poses[:, :3, 3] - poses[i, :3, 3], axis=1) < reach
        open_ &= ~((turn < degrees) & near_pose)
    return chosen


def most_agreed(agree: np.ndarray) -> int:
    """The index of the pose (row of ``agree`` (V, K) bool, the matches each brings within
    the threshold) that most matches agree with; the first on a tie."""
    return int(agree.sum(1).argmax())


# --- The scene search's trimmed fit (lower is better) ----------------------------------


def lowest(fits: np.ndarray, count: int) -> np.ndarray:
    """Indices of the ``count`` placements of least trimmed fit ``fits`` (B,), best first
    (a stable order: equals keep theirs)."""
    return np.argsort(fits, kind="stable")[:count]


def lowest_quarter(fits: np.ndarray, at_least: int) -> np.ndarray:
    """The placements that go on when the worst three quarters are dropped: :func:`lowest`
    of a quarter of them, at least ``at_least``."""
    return lowest(fits, max(len(fits) // 4, at_least))


def best_quarter(ordered: Sequence[T], at_least: int = 1) -> list[T]:
    """The first quarter of ``ordered`` (best first), at least ``at_least``: the refined
    placements that go on (:func:`least_first` orders them)."""
    return list(ordered[: max(len(ordered) // 4, at_least)])


def least_first(refined: Sequence[tuple[float, np.ndarray]]) -> list[tuple[float, np.ndarray]]:
    """``refined`` (fit, pose (4, 4)) pairs, least trimmed fit first (equals keep their
    order)."""
    return sorted(refined, key=lambda item: item[0])


def least_trimmed(refined: Sequence[tuple[float, np.ndarray]]) -> np.ndarray:
    """The pose of least trimmed fit among ``refined`` (fit, pose (4, 4)) pairs; the first
    on a tie."""
    return min(refined, key=lambda item: item[0])[1]


def polished(refined: Sequence[tuple[float, np.ndarray]], fallback: np.ndarray) -> np.ndarray:
    """The polish's answer: the pose of strictly least trimmed fit among ``refined`` (fit,
    pose) pairs, the first on a tie; ``fallback`` (4, 4) where none is finite. Unlike
    :func:`least_trimmed`, an infinite or NaN fit never wins."""
    best, best_fit = fallback, np.inf
    for fit, pose in refined:
        if fit < best_fit:
            best, best_fit = pose, fit
    return best

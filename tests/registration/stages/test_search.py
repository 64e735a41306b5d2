"""masknet.registration: the fit of a pose, and ICP from many starts."""

from __future__ import annotations

import numpy as np
from pykdtree.kdtree import KDTree
from scipy.spatial.transform import Rotation

from masknet.registration.judge.fit import pose_fit, pose_fits
from masknet.registration.solvers.icp import icp, icp_from_starts


def test_fit_counts_points_within_the_distance_and_batched_agrees():
    template = np.c_[np.arange(10.0), np.zeros((10, 2))]
    source = template[:4] + [0, 0.05, 0]
    far = np.eye(4)
    far[:3, 3] = [0, 1.0, 0]
    fit = pose_fit(KDTree(template), source, np.eye(4), 0.1)
    assert fit.fitness == 1.0 and abs(fit.rmse - 0.05) < 1e-12
    fits = pose_fits(KDTree(template), source, np.stack([np.eye(4), far]), 0.1)
    assert fits[0] == fit and fits[1].fitness == 0.0 and fits[1].score < fits[0].score


def test_icp_from_starts_equals_one_icp_per_start():
    rng = np.random.default_rng(1)
    template = rng.normal(size=(300, 3)) * [3, 2, 1]
    rot = Rotation.from_euler("xyz", [10, -20, 15], degrees=True).as_matrix()
    source = (template[:200] - [0.2, 0.1, 0]) @ rot
    starts = np.tile(np.eye(4), (3, 1, 1))
    starts[1, :3, :3] = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    starts[2, :3, :3] = Rotation.from_euler("x", 150, degrees=True).as_matrix()
    batched = icp_from_starts(KDTree(template), template, source, starts, 20)
    for h in range(3):
        one = icp(template, source, starts[h], 20, relative_rmse=0.0).transform[0]
        np.testing.assert_allclose(batched[h], one, atol=1e-8)


def _box_with_a_bump(rng: np.random.Generator) -> np.ndarray:
    """Points on a 2 x 1 x 0.5 box surface, and a bump at one corner that breaks the
    half-turn symmetry about its long axis."""
    faces = []
    for axis, size in enumerate((2.0, 1.0, 0.5)):
        for side in (-0.5, 0.5):
            p = rng.uniform(-0.5, 0.5, (300, 3)) * np.array([2.0, 1.0, 0.5])
            p[:, axis] = side * size
            faces.append(p)
    bump = np.array([0.8, 0.4, 0.25]) + rng.normal(0, 0.06, (200, 3))
    return np.concatenate(faces + [bump])


def test_an_early_flip_gives_way_to_the_pose_the_clouds_are_near():
    """A flip that passed the early exit gives way to the clouds as given when they
    refine to a better fit; an early answer that is right gets nothing added."""
    from masknet.registration.judge.arbiter import Candidate
    from masknet.registration.judge.prepared import FIT_SPACINGS, fit_clouds
    from masknet.registration.stages.search import (
        REFINE_TOLERANCE,
        _as_given,
        _short_icp_from_identity,
    )
    from masknet.registration.terms.options import RobustOptions

    rng = np.random.default_rng(0)
    template = _box_with_a_bump(rng)
    truth = np.eye(4)
    truth[:3, :3] = Rotation.from_euler("z", 20, degrees=True).as_matrix()
    source = (template - truth[:3, 3]) @ truth[:3, :3]  # truth moves source onto template
    flip = truth.copy()
    flip[:3, :3] = truth[:3, :3] @ Rotation.from_euler("x", 180, degrees=True).as_matrix()
    pair = fit_clouds(template, source, 4096)
    limit = FIT_SPACINGS * pair.spacing
    kept = pair.source[pair.surface]

    def early(pose: np.ndarray) -> list:
        return [Candidate(pose, "fpfh", pose_fit(pair.tree, kept, pose, limit))]

    options = RobustOptions()

    def refine(pose: np.ndarray, points: np.ndarray, kind: str) -> Candidate:
        cut = options.cut(pair.spacing)
        tf = icp(
            pair.template, points, pose, 60, REFINE_TOLERANCE, cut, template_tree=pair.tree
        ).transform[0]
        return Candidate(tf, kind, pose_fit(pair.tree, points, tf, limit))

    start = _short_icp_from_identity(pair.template, kept, 128, options.max_iterations)
    found = _as_given(early(flip), start, kept, pair.tree, limit, options, refine)
    assert len(found) == 1 and found[0].score > early(flip)[0].score
    angle = Rotation.from_matrix(found[0].pose[:3, :3] @ truth[:3, :3].T).magnitude()
    assert np.degrees(angle) < 1.0
    assert _as_given(early(truth), start, kept, pair.tree, limit, options, refine) == []


def test_candidates_a_few_spacings_apart_are_one_basin():
    from masknet.registration.judge.arbiter import Candidate, one_per_basin
    from masknet.registration.judge.fit import PoseFit

    turned = np.eye(4)
    turned[:3, :3] = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    shifted = np.eye(4)
    shifted[0, 3] = 0.05
    entries = [(np.eye(4), "a"), (shifted, "b"), (turned, "c")]
    wrap = [Candidate(pose, stage, PoseFit(1.0, 0.0, 1.0)) for pose, stage in entries]
    assert [e.stage for e in one_per_basin(wrap, 3, 0.1, 10.0)] == ["a", "c"]
    assert [e.stage for e in one_per_basin(wrap, 3, 0.01, 10.0)] == ["a", "b", "c"]


def test_the_answer_settles_from_a_looser_cut_where_the_verdict_calls_it_better():
    """The search's answer, stopped short of the truth, refined from a looser cut-off ends
    nearer the truth, fitting better and judged better; a `likely correct` answer is kept
    as it is."""
    from masknet.registration.judge.assessment import VERDICTS, judge
    from masknet.registration.stages.search import _Search
    from masknet.registration.terms.options import RobustOptions

    rng = np.random.default_rng(3)
    template = _box_with_a_bump(rng)
    truth = np.eye(4)
    truth[:3, :3] = Rotation.from_euler("z", 12, degrees=True).as_matrix()
    source = (template - truth[:3, 3]) @ truth[:3, :3]  # source -> template is ``truth``
    search = _Search(template, source, RobustOptions(inlier_iterations=3), {}, None)
    short = search.refine(np.eye(4), search.kept_source, "rotation")
    before = VERDICTS.index(judge(search.prepared.check(), short.pose).verdict)
    assert before > 0  # not likely correct
    settled = search.settle(short)
    assert settled is not short and settled.score > short.score

    def turn(pose: np.ndarray) -> float:
        return Rotation.from_matrix(pose[:3, :3] @ truth[:3, :3].T).magnitude()

    assert turn(settled.pose) < turn(short.pose)
    assert VERDICTS.index(judge(search.prepared.check(), settled.pose).verdict) < before
    search = _Search(template, source, RobustOptions(), {}, None)
    right = search.refine(truth, search.kept_source, "rotation")
    assert search.settle(right) is right
    assert turn(right.pose) < np.radians(0.5)

"""The rounds of Mask-X: later rounds start from the pose reached and use refined masks."""

from __future__ import annotations

import numpy as np
import pytest

from masknet import register
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.geometry.clouds import Frame
from masknet.registration.pipeline import REFINE_POINTS
from masknet.registration.solvers.backends import BackendRun
from masknet.registration.solvers.backends import icp as icp_backend
from masknet.registration.solvers.backends.base import keep_source_points
from masknet.registration.stages.refinement import NearestNeighbourMasks

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def pairs():
    shapes = load_modelnet40(bundled_sample_path()).points
    return make_test_pairs(shapes, 4, PairConfig(max_angle_deg=20, max_translation=0.3), seed=3)


def test_keep_source_points_drops_rejected_points_of_one_pair():
    source = np.arange(30, dtype=np.float64).reshape(1, 10, 3)
    keep = np.zeros((1, 10), bool)
    keep[0, [1, 4, 5, 8]] = True
    kept = keep_source_points(source, keep)
    # exactly the kept points, each once (a cycled fill would count some twice)
    np.testing.assert_array_equal(kept[0], source[0, [1, 4, 5, 8]])
    # a batch is left as it is: its back-ends take the mask or run pair by pair
    batch = np.repeat(source, 2, 0)
    np.testing.assert_array_equal(keep_source_points(batch, np.repeat(keep, 2, 0)), batch)
    # too few kept: unchanged
    few = np.zeros((1, 10), bool)
    few[0, :2] = True
    np.testing.assert_array_equal(keep_source_points(source, few), source)


class _Spy:
    """A back-end that records the source it is given and moves it by a fixed step."""

    def __init__(self) -> None:
        self.sources: list[np.ndarray] = []

    def __call__(self, template, source, mask, source_mask, options) -> BackendRun:
        kept = source if source_mask is None else source[:, source_mask[0]]
        self.sources.append(kept.copy())
        step = np.tile(np.eye(4), (len(source), 1, 1))
        step[:, :3, 3] = [0.01, 0.0, 0.0]
        return BackendRun(step, {})


@pytest.mark.parametrize("use_mask", [False, True])
def test_later_rounds_start_from_the_pose_reached(monkeypatch, pairs, use_mask):
    spy = _Spy()
    monkeypatch.setattr(icp_backend, "run_icp", spy)
    template, source = pairs.template[0].numpy(), pairs.source[0].numpy()
    result = register(template, source, method="icp", iterations=3, use_mask=use_mask)
    assert len(spy.sources) == 3
    frame = Frame.of(template[None].astype(np.float64))  # what the back-end sees
    for i in (1, 2):  # no centroid shift: exactly the source moved by the last round
        before = result.rounds[i - 1]
        expected = frame.points_in((source @ before[:3, :3].T + before[:3, 3])[None])[0]
        got = spy.sources[i][0]
        # 1e-6: the frame holds float32 values (6e-8 of the radius), rounded once before
        # the move here and once after it there
        if use_mask:  # the refiner's source mask picks rows; each row is a moved point
            distances = np.linalg.norm(got[:, None] - expected[None], axis=-1).min(1)
            assert distances.max() < 1e-6
        else:
            np.testing.assert_allclose(got, expected, atol=1e-6)


class _Astray:
    """A back-end whose first round is real ICP and whose later rounds throw the source
    half a radius off, as a learned back-end can."""

    def __init__(self, run_icp) -> None:
        self.run_icp, self.calls = run_icp, 0

    def __call__(self, template, source, mask, source_mask, options) -> BackendRun:
        self.calls += 1
        if self.calls == 1:
            return self.run_icp(template, source, mask, source_mask, options)
        step = np.tile(np.eye(4), (len(source), 1, 1))
        step[:, :3, 3] = [0.5, 0.0, 0.0]
        return BackendRun(step, {})


def test_a_refined_round_that_fits_worse_is_undone(monkeypatch, pairs):
    astray = _Astray(icp_backend.run_icp)
    monkeypatch.setattr(icp_backend, "run_icp", astray)
    template, source = pairs.template[0].numpy(), pairs.source[0].numpy()
    result = register(template, source, method="icp", iterations=3, refine_masks="nearest")
    assert astray.calls == 3
    # rounds 2 and 3 fitted worse than round 1's pose: both undone
    np.testing.assert_array_equal(result.rounds[1], result.rounds[0])
    np.testing.assert_array_equal(result.transformation, result.rounds[0])
    # the paper's loop (the network again each round) keeps every round, as the paper did
    monkeypatch.setattr(icp_backend, "run_icp", _Astray(astray.run_icp))
    paper = register(template, source, method="icp", iterations=2, refine_masks="network")
    assert np.abs(paper.rounds[1][:3, 3] - paper.rounds[0][:3, 3]).max() > 0.1


def test_the_papers_loop_recentres_every_round(monkeypatch, pairs):
    spy = _Spy()
    monkeypatch.setattr(icp_backend, "run_icp", spy)
    template, source = pairs.template[0].numpy(), pairs.source[0].numpy()
    register(template, source, method="icp", iterations=2, refine_masks="network")
    # round 2 re-centres: its source centroid sits on the masked template's centroid,
    # not where round 1 left it (0.01 further along x)
    first, second = spy.sources[0][0].mean(0), spy.sources[1][0].mean(0)
    np.testing.assert_allclose(first, second, atol=1e-9)


def test_refined_loop_with_the_rule_reaches_a_precise_mask(pairs):
    template, source = pairs.template.numpy(), pairs.source.numpy()
    truth = pairs.mask.numpy()
    for i in range(len(template)):
        one = register(template[i], source[i], iterations=1)
        three = register(template[i], source[i], method="icp", iterations=3, refine_masks="nearest")
        precision = (three.mask & truth[i]).sum() / three.mask.sum()
        assert precision >= 0.97, i  # the rule at a pose within a degree or so
        assert three.source_mask is not None and three.source_mask.all()
        angle = np.degrees(
            np.arccos(np.clip((np.trace(three.R.T @ _truth_R(pairs, i)) - 1) / 2, -1, 1))
        )
        angle_one = np.degrees(
            np.arccos(np.clip((np.trace(one.R.T @ _truth_R(pairs, i)) - 1) / 2, -1, 1))
        )
        assert angle <= max(angle_one, 0.5), i


def _truth_R(pairs, i: int) -> np.ndarray:
    return pairs.transform[i, :3, :3].double().numpy()


def test_refiner_masks_are_used_from_round_two(monkeypatch, pairs):
    calls = []

    class Recorder(NearestNeighbourMasks):
        def predict_masks(self, template, source):
            calls.append(source.copy())
            return super().predict_masks(template, source)

    template, source = pairs.template[1].numpy(), pairs.source[1].numpy()
    result = register(template, source, method="icp", iterations=3, refine_masks=Recorder())
    # rounds 2 and 3, then once at the pose returned
    assert len(calls) == 3
    last = result.rounds[-1]
    frame = Frame.of(template[None].astype(np.float64))  # what the refiner sees
    expected = frame.points_in((source @ last[:3, :3].T + last[:3, 3])[None])[0]
    np.testing.assert_allclose(calls[-1][0], expected, atol=1e-6)


def test_a_large_pair_loops_on_samples_and_masks_every_point():
    shape = load_modelnet40(bundled_sample_path()).points[0].astype(np.float64)
    rng = np.random.default_rng(0)
    # 3,072 points of one shape (three jittered copies), sampled to 512 for the network
    template = np.concatenate([shape + rng.normal(0, 0.004, shape.shape) for _ in range(3)])
    source = template[template[:, 0] > -0.2] + np.array([0.05, 0.0, 0.0])
    result = register(template, source, method="icp", iterations=3, max_points=512)
    assert result.sampled == (512, result.sampled[1]) and result.sampled[1] <= 512
    assert result.mask.shape == (len(template),) and result.source_mask.shape == (len(source),)
    # the source lies on the template: nearly every source point is kept, and the mask
    # covers mostly the part the source was cut from
    assert result.source_mask.mean() > 0.95
    assert (template[result.mask][:, 0] > -0.3).mean() > 0.9


class _TwoMasks:
    """Stands in for a two-sided network: fixed template and source masks."""

    def __init__(self, mask: np.ndarray, source_mask: np.ndarray) -> None:
        self.masks = mask, source_mask

    def predict_masks(self, template, source, *, k=None, threshold=None, precision="auto"):
        return self.masks


def test_a_batch_registers_each_pair_as_its_kept_source_points_alone(pairs):
    """Rejected source points leave a batch's ICP exactly as they leave a single pair's:
    they once were replaced by repeats of kept points, which then counted twice."""
    rng = np.random.default_rng(0)
    template = pairs.template.numpy().astype(np.float64)
    source = pairs.source.numpy().astype(np.float64)
    source = source + rng.normal(scale=0.01, size=source.shape)  # repeats would now weigh
    source_mask = np.ones(source.shape[:2], bool)
    for b in range(len(source)):  # a different share of each pair rejected
        source_mask[b, : 40 + 60 * b] = False
    mask = np.ones(template.shape[:2], bool)
    model = _TwoMasks(mask, source_mask)
    batch = register(template, source, method="icp", model=model, max_iterations=20)
    for b in range(len(source)):
        one = register(
            template[b],
            source[b],
            method="icp",
            model=_TwoMasks(mask[b : b + 1], source_mask[b : b + 1]),
            max_iterations=20,
        )
        np.testing.assert_allclose(batch.transform[b], one.transform, atol=2e-5)
        np.testing.assert_array_equal(batch.source_mask[b], source_mask[b])


def test_the_start_moves_the_kept_source_centroid_onto_the_masked_template_centroid():
    from masknet.registration.stages.rounds import initial_transform

    rng = np.random.default_rng(3)
    template = rng.normal(size=(2, 20, 3))
    source = rng.normal(size=(2, 12, 3)) + 5.0
    mask = rng.random((2, 20)) < 0.5
    keep = rng.random((2, 12)) < 0.7
    start = initial_transform("centroid", template, source, mask, keep)
    for b in range(2):
        moved = source[b] + start[b, :3, 3]
        np.testing.assert_allclose(moved[keep[b]].mean(0), template[b][mask[b]].mean(0))
    np.testing.assert_array_equal(
        initial_transform("identity", template, source, mask)[0], np.eye(4)
    )


# ------------------------------------------------------------ the default's refined rounds
def test_a_default_loop_starts_from_the_default_answer(pairs):
    template, source = pairs.template[0].numpy(), pairs.source[0].numpy()
    default = register(template, source)
    loop = register(template, source, iterations=3)
    assert loop.method == "auto" and len(loop.rounds) == 3
    np.testing.assert_allclose(loop.rounds[0], default.transform, atol=1e-9)
    assert loop.mask.shape == (len(template),) and loop.source_mask.shape == (len(source),)
    truth = pairs.mask[0].numpy()
    precision = (loop.mask & truth).sum() / loop.mask.sum()
    assert precision >= 0.9
    # the refined rounds do not walk away from a correct answer
    angle = np.degrees(np.arccos(np.clip((np.trace(loop.R.T @ _truth_R(pairs, 0)) - 1) / 2, -1, 1)))
    assert angle < 1.0


def test_the_refiner_sees_full_clouds_up_to_its_limit_and_the_pose_returned(pairs):
    calls = []

    class Recorder(NearestNeighbourMasks):
        def predict_masks(self, template, source):
            calls.append((template.copy(), source.copy()))
            return super().predict_masks(template, source)

    shape = load_modelnet40(bundled_sample_path()).points[0].astype(np.float64)
    rng = np.random.default_rng(1)
    template = np.concatenate([shape + rng.normal(0, 0.004, shape.shape) for _ in range(5)])
    source = template[template[:, 0] > -0.2] + np.array([0.05, 0.0, 0.0])
    result = register(template, source, iterations=2, refine_masks=Recorder())
    assert len(calls) == 2  # round 2, then once at the pose returned
    seen_template, seen_source = calls[-1]
    assert seen_template.shape[1] == REFINE_POINTS < len(template)  # 5,120 points sampled
    assert 0.3 * REFINE_POINTS < seen_source.shape[1] <= REFINE_POINTS
    assert result.mask.shape == (len(template),) and result.source_mask.shape == (len(source),)
    # the last call saw source points where the result puts them (in the frame it runs in)
    frame = Frame.of(template[None])
    moved = frame.points_in((source @ result.R.T + result.t)[None])[0]
    assert np.linalg.norm(seen_source[0][:, None] - moved[None], axis=-1).min(1).max() < 1e-6


def test_plain_rounds_after_the_default_have_no_mask_and_robust_takes_rounds(pairs):
    template, source = pairs.template[2].numpy(), pairs.source[2].numpy()
    plain = register(template, source, iterations=2, refine_masks=None)
    assert plain.mask is None and plain.source_mask is None and len(plain.rounds) == 2
    robust = register(template, source, method="robust", iterations=2)
    assert robust.method == "robust" and len(robust.rounds) == 2 and robust.mask is not None

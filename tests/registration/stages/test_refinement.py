"""The masks of rounds >= 2: the nearest-neighbour rule and the choice of refiner."""

from __future__ import annotations

import numpy as np
import pytest

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.errors import MaskNetError
from masknet.registration.stages.refinement import NearestNeighbourMasks, resolve_refiner


@pytest.fixture(scope="module")
def shape() -> np.ndarray:
    return load_modelnet40(bundled_sample_path(), "test").points[1].astype(np.float64)


def test_at_the_true_pose_the_rule_finds_the_overlap_and_the_outliers(shape):
    seen = shape[:, 0] > -0.1
    rng = np.random.default_rng(0)
    outliers = rng.uniform(-1, 1, (40, 3)) * 3 + np.array([4.0, 0, 0])  # off the shape
    source = np.concatenate([shape[seen], outliers])
    t_mask, s_mask = NearestNeighbourMasks().predict_masks(shape, source)
    assert s_mask[: seen.sum()].all() and not s_mask[seen.sum() :].any()
    assert t_mask.sum() == seen.sum()
    np.testing.assert_array_equal(t_mask, seen)


def test_the_rule_takes_batches(shape):
    source = shape[shape[:, 1] > 0]
    single = NearestNeighbourMasks().predict_masks(shape, source)
    batch = NearestNeighbourMasks().predict_masks(
        np.stack([shape, shape]), np.stack([source, source])
    )
    np.testing.assert_array_equal(batch[0][1], single[0])
    np.testing.assert_array_equal(batch[1][0], single[1])


def test_resolve_refiner():
    model = object()
    assert isinstance(resolve_refiner("nearest", model), NearestNeighbourMasks)
    assert resolve_refiner("network", model) is None and resolve_refiner(None, model) is None
    assert resolve_refiner("nearest", None) is None  # no mask at all: nothing to refine
    custom = NearestNeighbourMasks(2.0, 2.0)
    assert resolve_refiner(custom, model) is custom
    with pytest.raises(MaskNetError, match="unknown refine_masks 'closest'"):
        resolve_refiner("closest", model)
    with pytest.raises(MaskNetError, match="predict_masks"):
        resolve_refiner(42, model)
    with pytest.raises(MaskNetError, match="positive"):
        NearestNeighbourMasks(0.0)


def test_a_refined_round_that_fits_worse_is_undone(monkeypatch):
    """A round whose pose fits worse than its start (FIT_SLACK) is undone, and the rounds
    stop there; the pose returned is the start's."""
    # modules that bind icp at import do so before the patch
    import masknet.registration.solvers.icp as icp_module
    import masknet.registration.stages.auto  # noqa: F401
    import masknet.registration.stages.search  # noqa: F401
    from masknet.registration.stages.refinement import refine_pose

    g = np.random.default_rng(0)
    template = g.uniform(-1, 1, (800, 3))
    source = template[:500].copy()
    far = np.eye(4)
    far[:3, 3] = [3.0, 0.0, 0.0]  # nothing fits there

    def astray(template, source, init, **_):
        return icp_module.ICPSolution(far[None], np.array([True]), np.array([1]), 0.0, 0.0)

    monkeypatch.setattr(icp_module, "icp", astray)
    times = {"mask": 0.0, "register": 0.0}
    sampled = (np.arange(len(template)), np.arange(len(source)))
    out = refine_pose(template, source, sampled, np.eye(4), None, 3, 0.1, times)
    np.testing.assert_array_equal(out.transform, np.eye(4))
    assert len(out.rounds) == 3 and all((r == np.eye(4)).all() for r in out.rounds)


def test_refined_icp_pairs_with_the_wider_mask_and_the_narrow_one_is_returned(monkeypatch, shape):
    """The learned refiner's ICP sees the template points scoring >= ICP_THRESHOLD; the
    mask returned keeps those >= TEMPLATE_THRESHOLD."""
    import torch

    import masknet.registration.solvers.icp as icp_module
    from masknet.models.refine import RefineMaskNet
    from masknet.registration.stages import refinement

    torch.manual_seed(0)
    refiner = RefineMaskNet(k=6, local_channels=[8], point_channels=[16], head_channels=[8])
    # Scores spread over [0, 1] by the template point's x: 0.5 and 0.9 cut different sets.
    scores = 1 / (1 + np.exp(-4 * shape[:, 0]))
    monkeypatch.setattr(
        refiner, "predict", lambda t, s, *a, **k: (scores[None], np.ones((1, s.shape[1])))
    )
    used = []

    def record(template, source, init, **kwargs):
        used.append(len(template))
        return icp_module.ICPSolution(np.asarray(init)[None], [True], [0], 1.0, 0.0)

    monkeypatch.setattr(icp_module, "icp", record)
    times = {"mask": 0.0, "register": 0.0}
    sampled = (np.arange(len(shape)), np.arange(len(shape)))
    out = refinement.refine_pose(shape, shape, sampled, np.eye(4), refiner, 2, 0.1, times)
    wide = int((scores >= refinement.ICP_THRESHOLD).sum())
    narrow = int((scores >= refinement.TEMPLATE_THRESHOLD).sum())
    assert narrow < wide < len(shape)
    assert used == [wide, wide] and out.mask.sum() == narrow

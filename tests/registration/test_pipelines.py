"""The method table's adapters of ``auto`` and ``robust`` (auto_register, robust_register), with the
shipped MaskNet (auto's first look) and two-sided MaskNet (the search's), on ModelNet40
pairs with a known transform: a near one, which auto's fast path settles, and a far one
(150 degrees, outliers), which needs the coarse-to-fine search."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.geometry.sampling import NetworkClouds
from masknet.models import MaskNet, TwoSidedMaskNet
from masknet.registration.solvers.backends.base import MaskModels
from masknet.registration.stages.auto import PATHS
from masknet.registration.stages.auto import auto_register as run_auto
from masknet.registration.stages.robust import robust_register as run_robust
from masknet.registration.terms.options import RobustOptions
from masknet.registration.terms.result import Solution

pytestmark = pytest.mark.usefixtures("one_thread")

# info["path"], as documented (masknet.registration.stages.auto, .coarse)
AUTO_PATHS = set(PATHS) - {"scene search"}  # the scene search's is set by the facade
ROBUST_PATHS = {"correspondences", "search"}
SEARCH_ONLY = RobustOptions(correspondence_hypotheses=0)  # skip the FPFH hypotheses


@pytest.fixture(scope="module")
def networks() -> MaskModels:
    return MaskModels(MaskNet.pretrained(), TwoSidedMaskNet.pretrained())


@pytest.fixture(scope="module")
def far_pair():
    """A 70% view of a bundled shape (716 points), turned by 150 degrees about
    (0, 0.6, 0.8) and moved, with 60 uniform outliers appended: template (1, 1024, 3),
    source (1, 776, 3), the true transform (1, 4, 4) and the number of view points."""
    shape = load_modelnet40(bundled_sample_path()).points[3].astype(np.float64)
    view = shape[np.argsort(shape @ np.array([0.3, 0.8, 0.5]))[:716]]
    rotation = Rotation.from_rotvec(np.radians(150) * np.array([0.0, 0.6, 0.8])).as_matrix()
    shift = np.array([0.4, -0.2, 0.3])
    outliers = np.random.default_rng(0).uniform(-1, 1, size=(60, 3))
    source = np.concatenate([view, outliers]) @ rotation.T + shift
    truth = np.eye(4)
    truth[:3, :3], truth[:3, 3] = rotation.T, -rotation.T @ shift
    return shape[None], source[None], truth[None], len(view)


def _times() -> dict[str, float]:
    return {"sample": 0.0, "mask": 0.0, "register": 0.0, "refine": 0.0}


def _run(pipeline, template, source, models, options=None):
    """A pipeline on clouds small enough that the networks see them whole."""
    options = RobustOptions() if options is None else options
    nets = NetworkClouds.given(template, source)
    return pipeline(template, source, nets, models, options, _times(), "auto")


def test_auto_settles_near_pairs_on_its_fast_path(known_pairs, networks, pose_error):
    """Measured: 3.1e-7 deg and 9.6e-9 at most; bounds 1e-4 deg and 1e-6. The template
    mask marks the points the moved source covers: it overlaps the true overlap with an
    IoU of 0.92 and 0.94 (bound 0.85)."""
    t, s, truth, mask = known_pairs
    run = _run(run_auto, t, s, networks)
    assert isinstance(run, Solution)
    degrees, shift = pose_error(run.transform, truth)
    assert degrees.max() < 1e-4 and shift.max() < 1e-6, (degrees, shift)
    assert run.info["path"].tolist() == ["fast", "fast"]
    assert np.isnan(run.info["escalated_fitness"]).all()  # nothing escalated
    np.testing.assert_array_equal(run.info["fitness"], [1.0, 1.0])
    assert not run.info["ambiguous"].any()
    assert run.mask.shape == mask.shape and run.source_mask is None  # one-sided MaskNet
    iou = (run.mask & mask).sum(1) / (run.mask | mask).sum(1)
    assert iou.min() > 0.85, iou


def test_auto_escalates_a_far_pair_to_the_search(far_pair, networks, pose_error):
    """The fast path fits 0.85 of the source here (measured), under accept_fitness: the
    coarse-to-fine search takes over. Measured 0.032 deg and 4.1e-4; bounds 0.5 deg, 0.01."""
    t, s, truth, _ = far_pair
    run = _run(run_auto, t, s, networks)
    assert run.info["path"][0] in AUTO_PATHS - {"fast"}
    assert run.info["escalated_fitness"][0] < RobustOptions().accept_fitness
    degrees, shift = pose_error(run.transform, truth)
    assert degrees[0] < 0.5 and shift[0] < 0.01, (degrees, shift)
    assert run.info["fitness"][0] > 0.97 and not run.info["ambiguous"][0]
    assert set(run.info) >= {"path", "fitness", "inlier_rmse", "runner_up", "escalated_fitness"}


@pytest.mark.parametrize(
    ("options", "path"),
    [(RobustOptions(), "correspondences"), (SEARCH_ONLY, "search")],
)
def test_robust_recovers_a_far_pair(far_pair, networks, pose_error, options, path):
    """Measured: 0.032 deg (FPFH correspondences) and 0.033 deg (the search alone), 4.2e-4
    at most; bounds 0.5 deg and 0.01."""
    t, s, truth, _ = far_pair
    run = _run(run_robust, t, s, MaskModels(networks.search, None), options)
    assert run.info["path"].tolist() == [path] and path in ROBUST_PATHS
    degrees, shift = pose_error(run.transform, truth)
    assert degrees[0] < 0.5 and shift[0] < 0.01, (degrees, shift)
    assert "escalated_fitness" not in run.info  # auto's alone


def test_the_search_s_source_mask_rejects_the_outliers(far_pair, networks):
    """The two-sided mask, spread over every source point: it keeps 98.9% of the view and
    4 of the 60 outliers (measured); bounds 90% and 25%."""
    t, s, _, n_view = far_pair
    for pipeline, models in ((run_robust, MaskModels(networks.search, None)), (run_auto, networks)):
        run = _run(pipeline, t, s, models, SEARCH_ONLY)
        assert run.source_mask.shape == s.shape[:2]
        kept = run.source_mask[0]
        assert kept[:n_view].mean() > 0.9 and kept[n_view:].mean() < 0.25, (
            kept[:n_view].mean(),
            kept[n_view:].mean(),
        )


def test_without_networks_there_are_no_masks(known_pairs, far_pair, pose_error):
    t, s, truth, _ = known_pairs
    run = _run(run_auto, t, s, MaskModels(None, None))
    assert run.mask is None and run.source_mask is None
    assert set(run.info["path"]) <= AUTO_PATHS
    assert pose_error(run.transform, truth)[0].max() < 1e-4  # measured 3.1e-7 deg
    t, s, truth, _ = far_pair
    run = _run(run_robust, t, s, MaskModels(None, None), SEARCH_ONLY)
    assert run.mask is None and run.source_mask is None and run.info["path"][0] == "search"
    assert pose_error(run.transform, truth)[0][0] < 0.5  # measured 0.032 deg


class _Spy:
    """A mask network that counts its calls."""

    def __init__(self, network) -> None:
        self.network = network
        self.calls = 0

    def predict_masks(self, template, source, **kwargs):
        self.calls += 1
        return self.network.predict_masks(template, source, **kwargs)


def test_each_pipeline_masks_with_its_own_network(known_pairs, far_pair, networks):
    """auto: ``first`` on its fast path, once per pair, and ``search`` in the escalation
    (unless it is ``first``, whose masks then serve again); robust: ``first`` only."""
    t, s, _, _ = known_pairs
    first, search = _Spy(networks.first), _Spy(networks.search)
    _run(run_auto, t, s, MaskModels(first, search))
    assert (first.calls, search.calls) == (2, 0)  # two near pairs, no escalation

    t, s, _, _ = far_pair
    first, search = _Spy(networks.first), _Spy(networks.search)
    run = _run(run_auto, t, s, MaskModels(first, search), SEARCH_ONLY)
    assert run.info["path"][0] == "robust/search"
    assert (first.calls, search.calls) == (1, 1)

    both = _Spy(networks.search)
    run = _run(run_auto, t, s, MaskModels(both, both), SEARCH_ONLY)
    assert run.info["path"][0] == "robust/search" and both.calls == 1

    first, search = _Spy(networks.search), _Spy(networks.search)
    _run(run_robust, t, s, MaskModels(first, search), SEARCH_ONLY)
    assert (first.calls, search.calls) == (1, 0)

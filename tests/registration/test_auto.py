"""masknet.registration.auto: the default ``register`` with the shipped weights, on
partial pairs of the paper's protocol, against plain ICP."""

from __future__ import annotations

import numpy as np
import pytest

from masknet import register
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.evaluation.registration import pose_errors

pytestmark = pytest.mark.usefixtures("one_thread")


def _errors(pairs, **kwargs) -> np.ndarray:
    truth = pairs.transform.double().numpy()
    errors = []
    for i in range(len(truth)):
        result = register(pairs.template[i].numpy(), pairs.source[i].numpy(), **kwargs)
        errors.append(pose_errors(result.transform[None], truth[i : i + 1])[0][0])
    return np.array(errors)


def test_the_default_is_accurate_on_partial_pairs_and_far_ahead_of_icp():
    """40 seeded pairs (70% views, up to 45 deg). Measured: the default 0.013 deg mean,
    p90 7e-7 deg; ICP with 30 iterations 4.96 deg mean; no motion about 24 deg. RESULTS
    gives the default 0.39 deg mean over 100 pairs, so the floor is 0.2 deg here, with
    p90 under 0.01 deg and a tenth of ICP's mean."""
    shapes = load_modelnet40(bundled_sample_path(), "test").points
    pairs = make_test_pairs(shapes, 40, PairConfig(), seed=23)
    default = _errors(pairs)
    icp = _errors(pairs, method="icp", use_mask=False, max_iterations=30)
    assert default.mean() < 0.2 and np.percentile(default, 90) < 0.01, default
    assert default.mean() < 0.1 * icp.mean(), (default.mean(), icp.mean())


def test_with_outliers_the_fast_path_suffices_on_most_pairs_and_is_right():
    """10% uniform outliers: stray points that happen to lie close no longer count in the
    check, nor strays just beside the surface, so a right fast-path result passes it.
    Measured on these 20 pairs: 80% pass (0.035 deg mean); before strays were dropped, 55%;
    with one neighbour asked instead of two, 15%."""
    shapes = load_modelnet40(bundled_sample_path(), "test").points
    pairs = make_test_pairs(shapes, 20, PairConfig(outlier_ratio=0.1), seed=5)
    truth = pairs.transform.double().numpy()
    paths, errors = [], []
    for i in range(len(truth)):
        result = register(pairs.template[i].numpy(), pairs.source[i].numpy())
        paths.append(str(result.info["path"]))
        errors.append(pose_errors(result.transform[None], truth[i : i + 1])[0][0])
    fast = np.mean([p == "fast" for p in paths])
    assert fast >= 0.65, paths
    assert np.mean(errors) < 0.5, errors

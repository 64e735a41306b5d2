"""masknet.registration.many: many pairs in parallel give what one call at a time gives, in
order, a refused pair in its place; and the same on a local Dask cluster."""

from __future__ import annotations

import numpy as np
import pytest

from masknet import MaskNetError, register
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.registration.many import register_many


@pytest.fixture(scope="module")
def pairs() -> list[tuple[np.ndarray, np.ndarray]]:
    shapes = load_modelnet40(bundled_sample_path(), "test").points[:4]
    made = make_test_pairs(shapes, 4, PairConfig(), seed=8)
    return [(made.template[i].double().numpy(), made.source[i].double().numpy()) for i in range(4)]


def test_results_come_in_order_and_equal_single_calls(pairs, one_thread):
    bad = (pairs[0][0], np.full((10, 3), np.nan))
    results = register_many([*pairs, bad], workers=2, method="icp")
    assert len(results) == 5 and isinstance(results[4], MaskNetError)
    assert "NaN" in str(results[4])
    for (template, source), result in zip(pairs, results, strict=False):
        single = register(template, source, method="icp")
        np.testing.assert_allclose(result.transform, single.transform, atol=1e-9)


def test_a_local_dask_cluster_gives_the_same_results(pairs, one_thread):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        results = register_many(pairs, scheduler=cluster.scheduler_address, method="icp")
    for (template, source), result in zip(pairs, results, strict=True):
        single = register(template, source, method="icp")
        np.testing.assert_allclose(result.transform, single.transform, atol=1e-9)

"""Units: every method gives the same result for a real pair in metres and the same pair
in millimetres (the 3DMatch pair of ../shared/data/scans, 2,000 points a side), because
``register`` runs in one unit-free frame (:class:`masknet.geometry.clouds.Frame`)."""

from __future__ import annotations

import numpy as np
import pytest

from masknet import register
from masknet.evaluation.registration import pose_errors
from masknet.registration.methods import METHODS

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def real_pair(scans_dir):
    rng = np.random.default_rng(0)
    template = np.load(scans_dir / "geotransformer_demo_ref.npy")
    source = np.load(scans_dir / "geotransformer_demo_src.npy")
    return (
        template[rng.choice(len(template), 2000, replace=False)],
        source[rng.choice(len(source), 2000, replace=False)],
    )


@pytest.mark.parametrize("method", METHODS)
def test_metres_and_millimetres_give_the_same_transform(real_pair, method, o3d):
    template, source = real_pair
    metres = register(template, source, method=method)
    millimetres = register(1000 * template, 1000 * source, method=method)
    back = millimetres.transform.copy()
    back[:3, 3] /= 1000
    rotation, translation = pose_errors(metres.transform[None], back[None])
    radius = np.linalg.norm(template - template.mean(0), axis=1).max()
    # measured: 0 degrees and under 1e-15 of the radius for every method
    assert rotation[0] < 1e-6 and translation[0] < 1e-6 * radius, (rotation, translation)
    if metres.inlier_rmse is not None and np.isfinite(metres.inlier_rmse).all():
        np.testing.assert_allclose(1000 * metres.inlier_rmse, millimetres.inlier_rmse, rtol=1e-6)


def test_a_distance_given_in_input_units_follows_the_unit(real_pair):
    template, source = real_pair
    metres = register(template, source, method="icp", max_correspondence_distance=0.05)
    millimetres = register(
        1000 * template, 1000 * source, method="icp", max_correspondence_distance=50.0
    )
    np.testing.assert_allclose(metres.fitness, millimetres.fitness, rtol=1e-9)
    looser = register(template, source, method="icp", max_correspondence_distance=0.5)
    assert not np.allclose(looser.transform, metres.transform)  # the cut-off matters here

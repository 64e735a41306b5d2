"""Tests for masknet.registration.judge.fit.evaluate_registration: inlier fraction and RMSE of any transform."""

from __future__ import annotations

import numpy as np
import pytest

from masknet import MaskNetError, evaluate_registration
from masknet.data import bundled_sample_path, load_modelnet40
from masknet.geometry.clouds import median_spacing
from masknet.registration.terms.options import DEFAULT_SPACINGS


@pytest.fixture(scope="module")
def shape() -> np.ndarray:
    return load_modelnet40(bundled_sample_path(), "test").points[2].astype(np.float64)


def _moved(
    points: np.ndarray, angle_deg: float, shift: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """points turned about z and shifted, and the transform that takes them back."""
    a = np.radians(angle_deg)
    rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    back = np.eye(4)
    back[:3, :3], back[:3, 3] = rot.T, -rot.T @ shift
    return points @ rot.T + shift, back


def test_the_true_transform_fits_every_point(shape):
    source, back = _moved(shape[:600], 40.0, np.array([0.5, -0.2, 0.1]))
    quality = evaluate_registration(template=shape, source=source, transform=back)
    assert quality.fitness == pytest.approx(1.0)
    assert quality.inlier_rmse == pytest.approx(0.0, abs=1e-9)
    assert quality.max_correspondence_distance == pytest.approx(
        DEFAULT_SPACINGS * median_spacing(shape)
    )


def test_a_wrong_transform_fits_fewer_points(shape):
    source, back = _moved(shape[:600], 40.0, np.zeros(3))
    right = evaluate_registration(template=shape, source=source, transform=back).fitness
    wrong = evaluate_registration(template=shape, source=source, transform=np.eye(4)).fitness
    far = np.eye(4)
    far[:3, 3] = 10.0  # the source moved well away from the template
    assert wrong < 0.7 * right
    assert evaluate_registration(template=shape, source=source, transform=far).fitness == 0.0
    assert (
        evaluate_registration(template=shape, source=source, transform=far).inlier_rmse == 0.0
    )  # none, as Open3D


def test_the_default_distance_does_not_depend_on_the_unit(shape):
    source, _ = _moved(shape[:600], 15.0, np.array([0.05, 0.0, 0.0]))
    metres = evaluate_registration(template=shape, source=source, transform=np.eye(4))
    millimetres = evaluate_registration(
        template=1000 * shape, source=1000 * source, transform=np.eye(4)
    )
    assert 0 < metres.fitness < 1
    assert millimetres.fitness == pytest.approx(metres.fitness)
    assert millimetres.inlier_rmse == pytest.approx(1000 * metres.inlier_rmse)


def test_batches_and_an_explicit_distance(shape):
    source, back = _moved(shape[:600], 20.0, np.zeros(3))
    quality = evaluate_registration(
        template=np.stack([shape, shape]),
        source=np.stack([source, source]),
        transform=np.stack([back, np.eye(4)]),
        max_correspondence_distance=1e-6,
    )
    assert quality.fitness.shape == (2,)
    assert quality.fitness[0] == pytest.approx(1.0) and quality.fitness[1] < 0.5
    np.testing.assert_allclose(quality.max_correspondence_distance, [1e-6, 1e-6])


@pytest.mark.parametrize(
    "transform, distance, words",
    [
        (np.eye(3), None, "transform must be"),
        (np.full((4, 4), np.nan), None, "transform holds NaN or inf"),
        (2 * np.eye(4), None, "must be rigid"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), None, "must be rigid"),
        (np.eye(4), -1.0, "max_correspondence_distance"),
        (np.eye(4), float("nan"), "max_correspondence_distance"),
        (np.eye(4), "0.1", "max_correspondence_distance"),
    ],
)
def test_bad_arguments_are_one_clear_error(shape, transform, distance, words):
    with pytest.raises(MaskNetError, match=words):
        evaluate_registration(
            template=shape,
            source=shape[:100],
            transform=transform,
            max_correspondence_distance=distance,
        )


def test_a_positional_call_is_refused(shape):
    """Open3D's evaluate_registration takes (source, target, distance, transformation): a
    call in either order by position would measure some cloud; only names are taken."""
    source, back = _moved(shape[:600], 20.0, np.zeros(3))
    with pytest.raises(TypeError):
        evaluate_registration(shape, source, back)
    with pytest.raises(TypeError):
        evaluate_registration(source, shape, 0.01, back)  # Open3D's order
    with pytest.raises(TypeError):
        evaluate_registration(shape, source=source, transform=back)


def test_the_former_name_max_distance_still_works_with_a_warning():
    rng = np.random.default_rng(0)
    shape = rng.normal(size=(200, 3))
    new = evaluate_registration(
        template=shape, source=shape, transform=np.eye(4), max_correspondence_distance=0.01
    )
    with pytest.warns(DeprecationWarning, match="max_correspondence_distance"):
        old = evaluate_registration(
            template=shape, source=shape, transform=np.eye(4), max_distance=0.01
        )
    np.testing.assert_array_equal(np.array(old), np.array(new))
    assert float(new.fitness) == 1.0

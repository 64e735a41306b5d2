"""Real data from ../shared/data/scans (present in CI; elsewhere these tests skip): the
carton found in the cluttered Kinect scene against its established pose, and pairs cut
from the evaluation scans for the shipped scan weights' mask precision and the default's
registration. Floors are stated margins under what these seeded pairs measure; the
3DMatch pair is checked through the benchmark (tests/experiments)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from masknet import MaskNet, register
from masknet.evaluation.registration import pose_errors
from masknet.io import read_points
from masknet.models import TwoSidedMaskNet

pytestmark = pytest.mark.usefixtures("one_thread")

CARTON_TRUTH = Path(__file__).parents[1] / "docs" / "results" / "carton" / "ground_truth.txt"


@pytest.fixture(scope="module", params=[True, False], ids=["shared points", "re-sampled"])
def scan_pairs(request, scans_dir):
    """Two pairs per evaluation scan (14): 70% views of 4,096-point templates, up to 45
    degrees, noise 0.2% of the radius; the source copied from the template or re-sampled."""
    from masknet.experiments.rounds import scan_eval_pairs

    return scan_eval_pairs(2, request.param, seed=0)


def test_the_default_registers_the_two_room_scans(scans_dir, o3d):
    """Two laser scans of one room, 2 m and 41 degrees apart, each crowded at its
    scanner's feet. The reference is independent of masknet: Open3D's point-to-plane ICP
    from the robot's odometry that PCL's tutorial publishes, on even 5 cm grids (the
    benchmark's consensus, reached there from every start). Measured 0.5 degrees and
    1.6 cm; before the fit used even subsets, the default returned the scans as given,
    41 degrees off."""
    from masknet.experiments.real_pairs import refine_on_grid, room_odometry

    template = read_points(scans_dir / "room_scan1.pcd", drop_nonfinite=True)
    source = read_points(scans_dir / "room_scan2.pcd", drop_nonfinite=True)
    reference, _ = refine_on_grid(template, source, room_odometry())
    result = register(template, source)
    rotation, translation = pose_errors(result.transform[None], reference[None])
    assert rotation[0] < 1.0 and translation[0] < 0.05, (rotation, translation)


@pytest.fixture(scope="module")
def thinned_rooms(scans_dir, o3d):
    """The two room scans at 5,000 source points (6,000 template points), draw 5 of
    scripts/density_draws.py, and the reference pose of the test above."""
    from masknet.experiments.real_pairs import refine_on_grid, room_odometry

    template = read_points(scans_dir / "room_scan1.pcd", drop_nonfinite=True)
    source = read_points(scans_dir / "room_scan2.pcd", drop_nonfinite=True)
    reference, _ = refine_on_grid(template, source, room_odometry())
    rng = np.random.default_rng([5000, 5])
    source = source[rng.choice(len(source), 5000, replace=False)]
    template = template[rng.choice(len(template), 6000, replace=False)]
    return template, source, reference


def test_thinned_room_scans_are_judged_on_even_halves(thinned_rooms, monkeypatch):
    """A random subset of a laser scan crowds at the scanner's feet. Judged as given, the
    reference pose read `uncertain` and the scans as given (41 degrees, 2 m off) `likely
    correct`; on even halves the reference reads `likely correct` and the scans as given
    do not."""
    from masknet import assess_registration
    from masknet.registration.judge import prepared

    template, source, reference = thinned_rooms
    assert assess_registration(template, source, reference).verdict == "likely correct"
    assert assess_registration(template, source, np.eye(4)).verdict != "likely correct"
    monkeypatch.setattr(prepared, "UNEVEN_SPREAD", np.inf)
    assert assess_registration(template, source, reference).verdict != "likely correct"
    assert assess_registration(template, source, np.eye(4)).verdict == "likely correct"


def test_thinned_room_scans_do_not_slide_along_the_room(thinned_rooms, monkeypatch):
    """RANSAC keeps a pose slid 2.2 m along the room (it lays more points on the other
    scan); the translation that most matches vote for elsewhere, under its rotation, is the
    right one, and the verdict ranks it higher. Measured 0.17 degrees and 1.0 cm; without
    the slid pose 2.2 m off."""
    import masknet.registration.stages.consensus as consensus

    template, source, reference = thinned_rooms
    result = register(template, source)
    rotation, translation = pose_errors(result.transform[None], reference[None])
    assert rotation[0] < 1.0 and translation[0] < 0.05, (rotation, translation)
    monkeypatch.setattr(consensus, "_slid_pose", lambda *args: None)
    result = register(template, source)
    assert pose_errors(result.transform[None], reference[None])[1][0] > 1.0


def _precision(predicted: np.ndarray, truth: np.ndarray) -> float:
    return float((predicted & truth).sum() / max(predicted.sum(), 1))


def test_the_default_finds_the_carton_in_the_cluttered_scene(scans_dir):
    """Measured 0.012 deg and 0.16 mm from the established pose (scripts/carton_scene.py)."""
    template = read_points(scans_dir / "milk.pcd", drop_nonfinite=True)
    scene = read_points(scans_dir / "milk_cartoon_all_small_clorox.pcd", drop_nonfinite=True)
    result = register(template, scene)
    rotation, translation = pose_errors(result.transform[None], np.loadtxt(CARTON_TRUTH)[None])
    assert result.info["path"] == "scene search"
    assert rotation[0] < 0.5 and translation[0] < 0.002, (rotation, translation)


@pytest.mark.parametrize(("name", "floor"), [("scans", 0.78), ("two-sided", 0.76)])
def test_scan_weights_beat_chance_on_real_scan_pairs(scan_pairs, name, floor):
    """Template-mask precision; chance is 0.70. Measured (shared / re-sampled):
    masknet_scans 0.824 / 0.809, masknet2_scans 0.799 / 0.789."""
    model = TwoSidedMaskNet.pretrained() if name == "two-sided" else MaskNet.pretrained("scans")
    precision = []
    for template, source, truth in zip(
        scan_pairs.template, scan_pairs.source, scan_pairs.mask, strict=True
    ):
        if name == "two-sided":
            mask = model.predict_masks(template.numpy(), source.numpy())[0]
        else:
            mask = model.predict_mask(template.numpy(), source.numpy())
        precision.append(_precision(mask, truth.numpy()))
    assert np.mean(precision) > floor, np.mean(precision)


def test_the_default_and_the_refined_loop_on_real_scan_pairs(scan_pairs):
    """Errors on these 14 pairs are heavy-tailed (a few hard pairs land 5-60 deg off, and
    which ones moves with float rounding), so the floors are on the median and on the
    count of misses. Measured (shared / re-sampled): the default's median 0.021 / 0.47 deg,
    pairs beyond 5 deg 2 / 3; the loop (the default, then two refined rounds) median
    0.041 / 0.155 deg, misses 0 / 2, its mask's precision 0.954 / 0.958. No motion is about
    25 deg. Floors: median 1 deg (the loop 0.4), at most 5 misses, precision 0.92."""
    truth = scan_pairs.transform.double().numpy()
    errors, loop_errors, precision = [], [], []
    for i in range(len(truth)):
        template, source = scan_pairs.template[i].numpy(), scan_pairs.source[i].numpy()
        result = register(template, source)
        errors.append(pose_errors(result.transform[None], truth[i : i + 1])[0][0])
        loop = register(template, source, iterations=3)
        loop_errors.append(pose_errors(loop.transform[None], truth[i : i + 1])[0][0])
        precision.append(_precision(loop.mask, scan_pairs.mask[i].numpy()))
    errors, loop_errors = np.array(errors), np.array(loop_errors)
    assert np.median(errors) < 1.0 and (errors > 5).sum() <= 5, errors
    assert np.median(loop_errors) < 0.4 and (loop_errors > 5).sum() <= 5, loop_errors
    assert np.mean(precision) > 0.92, precision

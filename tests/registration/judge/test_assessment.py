"""assess_registration: each rule of the verdict, alone and through the whole measure."""

import numpy as np
import pytest
import torch

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.errors import MaskNetError
from masknet.geometry.se3 import so3_exp
from masknet.registration.judge.assessment import (
    CORRECT_DEG,
    CORRECT_FIT,
    CORRECT_SHIFT,
    RULE_VERDICTS,
    WRONG_DEG,
    WRONG_FIT,
    WRONG_SHIFT,
    assess_registration,
    verdict_rule,
)


@pytest.fixture(scope="module")
def shape() -> np.ndarray:
    return load_modelnet40(bundled_sample_path()).points[3].astype(np.float64)


def turned(points: np.ndarray, degrees: float, shift: float = 0.0) -> np.ndarray:
    """(4, 4): a turn by ``degrees`` about a fixed axis through the points' centroid, then a
    shift of ``shift`` along x."""
    axis = np.array([0.3, 0.8, 0.5]) / np.linalg.norm([0.3, 0.8, 0.5])
    rotation = so3_exp(torch.tensor(axis * np.radians(degrees))).numpy()
    pose = np.eye(4)
    centre = points.mean(0)
    pose[:3, :3] = rotation
    pose[:3, 3] = centre - rotation @ centre + [shift, 0.0, 0.0]
    return pose


@pytest.mark.parametrize(
    ("overlap_fit", "degrees", "shift", "rule"),
    [
        (WRONG_FIT - 0.01, 0.0, 0.0, "overlap"),  # a poor fit, however near
        (1.0, WRONG_DEG, 0.0, "nearby"),  # a fit as far as WRONG_DEG
        (1.0, 0.0, WRONG_SHIFT, "nearby"),  # or as far as WRONG_SHIFT
        (WRONG_FIT - 0.01, WRONG_DEG, 0.0, "overlap"),  # the overlap rule comes first
        (CORRECT_FIT, CORRECT_DEG, CORRECT_SHIFT, "correct"),  # every bound inclusive
        (CORRECT_FIT - 0.01, 0.0, 0.0, "between"),  # fits, but not well enough
        (1.0, CORRECT_DEG + 0.1, 0.0, "between"),  # a few degrees from the fit
        (1.0, 0.0, CORRECT_SHIFT + 0.01, "between"),  # a little shifted from it
    ],
)
def test_each_rule_decides_at_its_bound(overlap_fit, degrees, shift, rule):
    assert verdict_rule(overlap_fit, degrees, shift) == rule


def test_the_rules_give_the_three_verdicts():
    assert sorted(set(RULE_VERDICTS.values())) == ["likely correct", "likely wrong", "uncertain"]


@pytest.mark.parametrize(
    ("degrees", "shift", "verdict", "reason"),
    [
        (0.0, 0.0, "likely correct", "at the nearest fit"),
        (2.0, 0.0, "likely correct", "at the nearest fit"),
        (5.0, 0.0, "uncertain", "at the nearest fit"),
        (10.0, 0.0, "likely wrong", "fits better"),  # the nearby rule, by its angle
        (0.0, 0.3, "likely wrong", "fits better"),  # the nearby rule, by its shift
        (0.0, 6.0, "likely wrong", "only 0% of the overlap"),  # nothing near: the overlap rule
    ],
)
def test_verdict_of_poses_off_the_truth(shape, degrees, shift, verdict, reason):
    partial = shape[shape[:, 0] < np.quantile(shape[:, 0], 0.7)]
    check = assess_registration(shape, partial, turned(partial, degrees, shift))
    assert check.verdict == verdict, check
    assert reason in check.reason
    if verdict != "likely wrong" or shift < 1:
        # The nearest fit is the truth: a short ICP finds the turn that was made.
        assert check.nearby_deg == pytest.approx(degrees, abs=0.2)


def test_a_wrong_pose_whose_nearest_fit_fits_well_is_caught_by_distance(shape):
    """10 degrees off: the overlap fit at the nearest fit is perfect, so only the distance
    to that fit can say the pose is wrong."""
    check = assess_registration(shape, shape, turned(shape, 10.0))
    assert check.overlap_fit >= CORRECT_FIT
    assert check.nearby_deg >= WRONG_DEG
    assert check.verdict == "likely wrong"


def test_units_do_not_change_the_verdict(shape):
    pose = turned(shape, 5.0)
    in_mm = pose.copy()
    in_mm[:3, 3] *= 1000
    a = assess_registration(shape, shape, pose)
    b = assess_registration(shape * 1000, shape * 1000, in_mm)
    assert a.verdict == b.verdict == "uncertain"
    assert b.max_correspondence_distance == pytest.approx(1000 * a.max_correspondence_distance)
    assert b.nearby_deg == pytest.approx(a.nearby_deg, abs=1e-3)


def test_a_given_distance_is_used(shape):
    check = assess_registration(shape, shape, np.eye(4), max_correspondence_distance=0.05)
    assert check.max_correspondence_distance == 0.05


@pytest.mark.parametrize(
    ("template", "source", "transform", "match"),
    [
        ("batch", "batch", np.eye(4), "one pair"),
        (None, None, np.full((4, 4), np.nan), "transform"),
        (None, None, np.diag([2.0, 1.0, 1.0, 1.0]), "rigid"),
    ],
)
def test_refusals(shape, template, source, transform, match):
    template = {None: shape, "batch": np.stack([shape, shape])}[template]
    source = {None: shape, "batch": np.stack([shape, shape])}[source]
    with pytest.raises(MaskNetError, match=match):
        assess_registration(template, source, transform)


@pytest.mark.parametrize("scale", [1.0, 1e-3, 1e3])
@pytest.mark.parametrize("degrees", [0.0, 2.0, 5.0, 10.0, 45.0])
def test_the_nearest_fit_is_the_same_with_and_without_open3d(shape, degrees, scale, o3d):
    """The verdict's short ICP is Open3D's where the pair was prepared for it (the
    consensus front end), the project's elsewhere: the same algorithm, so the same verdict
    and nearly the same nearest fit, in any unit (Open3D's stopping rule is absolute: it
    is given in inlier distances)."""
    from masknet.registration.judge.assessment import judge, prepare_check

    partial = shape[shape[:, 0] < np.quantile(shape[:, 0], 0.7)]
    pose = turned(partial, degrees)
    pose[:3, 3] *= scale
    with_open3d = judge(prepare_check(scale * shape, scale * partial, open3d=True), pose)
    without = judge(prepare_check(scale * shape, scale * partial), pose)
    assert with_open3d.verdict == without.verdict
    assert with_open3d.nearby_deg == pytest.approx(without.nearby_deg, abs=0.2)
    assert with_open3d.overlap_fit == pytest.approx(without.overlap_fit, abs=0.02)


def test_a_verdict_does_not_import_open3d():
    """Open3D takes about a second to import: a command-line verdict must not pay it."""
    import subprocess
    import sys

    code = (
        "import sys, numpy as np\n"
        "from masknet import assess_registration\n"
        "p = np.random.default_rng(0).normal(size=(500, 3))\n"
        "assess_registration(p, p[:300], np.eye(4))\n"
        "print('open3d' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_uneven_clouds_are_judged_on_even_halves():
    """A plane sampled evenly keeps every point; the same plane with most of its points
    crowded in one corner (a laser scan at its scanner's feet) is halved, evenly; clouds of
    fewer than MIN_HALVED points keep theirs."""
    from masknet.registration.judge.assessment import MIN_HALVED, even_pair

    rng = np.random.default_rng(0)
    even = np.c_[rng.uniform(0, 10, (6000, 2)), np.zeros(6000)]
    crowded = np.c_[
        np.r_[rng.uniform(0, 10, (2000, 2)), rng.uniform(0, 1, (4000, 2))], np.zeros(6000)
    ]
    template, source = even_pair(even, even[::-1])
    assert len(template) == len(source) == 6000
    template, source = even_pair(even, crowded)
    assert len(template) < 3001 and len(source) < 3001
    assert (source[:, :2] > 1).all(1).mean() > 0.5  # the crowd no longer outnumbers the rest
    small = np.r_[crowded[:600], crowded[2000 : 1999 + MIN_HALVED - 600]]  # crowded too
    assert len(even_pair(small, small)[0]) == MIN_HALVED - 1
    assert len(even_pair(np.r_[small, crowded[-1:]], np.r_[small, crowded[-1:]])[0]) < 1100
    assert len(even_pair(even, crowded, halve_uneven=False)[1]) == 6000

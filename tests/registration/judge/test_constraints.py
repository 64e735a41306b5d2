"""The verdict sees a slide: shapes that leave a motion free, and a pose moved along it."""

import numpy as np
import pytest

from masknet.geometry.knn import cloud_tree
from masknet.registration.judge.assessment import (
    FREE_RATIO,
    SLIDE_GAIN,
    assess_registration,
    verdict_rule,
)
from masknet.registration.judge.constraints import (
    best_slide,
    covering_slide,
    describe_free,
    pose_constraint,
)

RNG = np.random.default_rng(0)


def _square(count: int, size: tuple[float, float] = (1.0, 1.0)) -> np.ndarray:
    """(count, 3) points on the square [0, size] in z = 0."""
    return np.c_[RNG.uniform(0, 1, (count, 2)) * size, np.zeros(count)]


def _plane() -> np.ndarray:
    return _square(3000)


def _crease() -> np.ndarray:
    """A floor (z = 0) and a wall (y = 0): they meet along x."""
    return np.r_[_square(1500), _square(1500)[:, [0, 2, 1]]]


def _corridor() -> np.ndarray:
    """A floor 1 wide and two walls at x = 0 and x = 1, all 3 long in y."""
    wall = _square(1000, (3.0, 1.0))[:, [2, 0, 1]]
    return np.r_[_square(1500, (1.0, 3.0)), wall, wall + [1.0, 0.0, 0.0]]


def _cylinder() -> np.ndarray:
    """Radius 1 about z, 2 long; dense, so that its normals hardly tilt along it."""
    angle, height = RNG.uniform(0, 2 * np.pi, 16000), RNG.uniform(0, 2, 16000)
    return np.c_[np.cos(angle), np.sin(angle), height]


def _corner() -> np.ndarray:
    """Three faces of a box: every motion is pinned."""
    return np.r_[_square(1000), _square(1000)[:, [0, 2, 1]], _square(1000)[:, [2, 0, 1]]]


def _slid(direction: tuple[float, float, float], distance: float) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, 3] = distance * np.asarray(direction)
    return pose


def _turned_about_z(degrees: float) -> np.ndarray:
    angle = np.radians(degrees)
    pose = np.eye(4)
    pose[:2, :2] = [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
    return pose


# Each shape, a pose moved along a motion it leaves free, how that motion reads, and
# whether the shape leaves it free to the last bit (under FREE_RATIO: a plane, a cylinder)
# or only nearly (a crease and a corridor, whose normals tilt where their faces meet).
DEGENERATE = [
    (
        _plane,
        _slid((0.6, 0.8, 0.0), 0.1),
        "slide within the plane normal to (0.00, 0.00, 1.00)",
        True,
    ),
    (_crease, _slid((1.0, 0.0, 0.0), 0.1), "slide along (1.00, 0.00, 0.00)", False),
    (_corridor, _slid((0.0, 1.0, 0.0), 0.3), "slide along (0.00, 1.00, 0.00)", False),
    (_cylinder, _slid((0.0, 0.0, 1.0), 0.2), "slide along (0.00, 0.00, 1.00)", True),
    (_cylinder, _turned_about_z(10.0), "turn about (0.00, 0.00, 1.00) through (0, 0, ", True),
]


@pytest.mark.parametrize(("make", "pose", "words", "exactly"), DEGENERATE)
def test_a_pose_moved_along_a_free_motion_is_not_likely_correct(make, pose, words, exactly):
    """The fit on these shapes is as good at the moved pose as at the right one (or better
    only where the moved pose hangs over an edge): the verdict cannot call it correct, and
    it names the motion left free."""
    template = make()
    source = template[::2]
    check = assess_registration(template, source, pose)
    assert check.verdict in ("uncertain", "likely wrong"), check
    if exactly:
        assert check.constraint < FREE_RATIO
        assert any(free.startswith(words) for free in check.free_directions), check
        assert words in check.reason
    else:
        assert check.least_pinned.startswith(words), check


def test_a_plane_is_uncertain_even_at_its_right_pose():
    """Nothing tells the right pose of a plane from one slid along it: not likely correct,
    with the reason naming what is free."""
    plane = _plane()
    check = assess_registration(plane, plane[::2], np.eye(4))
    assert check.verdict == "uncertain", check
    assert "does not pin the pose: free to slide within the plane normal to (0.00, 0.00, 1.00)" in (
        check.reason
    )


def test_a_plane_leaves_two_slides_and_a_turn_free():
    plane = _plane()
    constraint = pose_constraint(plane, cloud_tree(plane), plane[::2], 0.05)
    assert (constraint.ratios[:3] < FREE_RATIO).all() and constraint.ratios[3] > 0.1
    words = describe_free(constraint, FREE_RATIO)
    assert "slide within the plane normal to (0.00, 0.00, 1.00)" in words
    assert sum(w.startswith("turn about (0.00, 0.00, 1.00)") for w in words) == 1


@pytest.mark.parametrize("degrees", [0.0, 1.0])
def test_a_box_corner_pins_every_motion(degrees):
    """Three faces hold every slide and turn: the right pose (and one a degree off) stays
    likely correct, with nothing free."""
    corner = _corner()
    check = assess_registration(corner, corner[::2], _turned_about_z(degrees))
    assert check.verdict == "likely correct", check
    assert check.free_directions == ()
    assert check.constraint > 10 * FREE_RATIO


def test_a_modelnet_shape_is_pinned_at_its_pose():
    from masknet.data import bundled_sample_path, load_modelnet40

    shape = load_modelnet40(bundled_sample_path()).points[3].astype(np.float64)
    check = assess_registration(
        shape, shape[shape[:, 0] < np.quantile(shape[:, 0], 0.7)], np.eye(4)
    )
    assert check.verdict == "likely correct", check
    assert check.free_directions == ()


def test_a_slide_back_along_a_table_brings_the_box_onto_the_box():
    """A box on a table, the source slid along the table: the table fits wherever it lies,
    but a slide back along the table's free directions brings the box onto the box."""
    table = _square(6000, (2.0, 2.0))
    walls = [([0, 2, 1], [0.8, 0.8, 0.0]), ([0, 2, 1], [0.8, 1.2, 0.0])]
    walls += [([2, 0, 1], [0.8, 0.8, 0.0]), ([2, 0, 1], [1.2, 0.8, 0.0])]
    faces = [_square(200, (0.4, 0.4))[:, order] + shift for order, shift in walls]
    box = np.concatenate([_square(400, (0.4, 0.4)) + [0.8, 0.8, 0.4], *faces])
    template = np.r_[table, box]
    tree = cloud_tree(template)
    slid = template[::2] + [0.12, 0.16, 0.0]
    slide = best_slide(tree, template, slid, 0.04, pose_constraint(template, tree, slid, 0.04))
    assert slide.gain >= SLIDE_GAIN
    assert slide.offset @ [0.6, 0.8, 0.0] < -0.05  # back, towards the box
    right = best_slide(
        tree, template, template[::2], 0.04, pose_constraint(template, tree, template[::2], 0.04)
    )
    assert right.gain < SLIDE_GAIN  # at the right pose no slide fits better


def test_a_view_slid_off_the_end_of_a_channel_is_seen_by_what_it_covers():
    """A channel (a floor and two walls, 3 long in y) closed at y = 0 by an end wall, and a
    view of its first 70%, slid 0.3 along it: its end wall hangs in the channel, off the
    template, and the template's strip behind it is uncovered. The view slid back covers
    more of both clouds; at the truth no slide does."""
    floor = _square(3000, (1.0, 3.0))
    wall = _square(1500, (3.0, 0.5))[:, [2, 0, 1]]
    end = _square(500, (1.0, 0.5))[:, [0, 2, 1]]
    template = np.r_[floor, wall, wall + [1.0, 0.0, 0.0], end]
    tree = cloud_tree(template)
    view = template[template[:, 1] < 2.1][::2]
    slid = view + [0.0, 0.3, 0.0]
    found = covering_slide(tree, template, slid, 0.04, pose_constraint(template, tree, slid, 0.04))
    assert found.gain > 0.05
    assert found.offset[1] < -0.2  # back along the channel, towards its end wall
    right = covering_slide(tree, template, view, 0.04, pose_constraint(template, tree, view, 0.04))
    assert right.gain == 0.0  # at the truth no slide covers more of both


@pytest.mark.parametrize("seed", range(4))
def test_the_slide_search_finds_what_trying_every_slide_finds(seed):
    """The search fits the template's side only where the source's side gains; trying every
    slid pose both ways gives the same best slide."""
    from masknet.geometry.clouds import rms_radius
    from masknet.registration.judge.constraints import SEARCH_POINTS, SEARCHED_MOTIONS, SLIDE_STEPS
    from masknet.registration.judge.fit import overlap_fits

    rng = np.random.default_rng(seed)
    table = _square(3000, (2.0, 2.0))
    box = _square(300, (0.4, 0.4)) + [0.8, 0.8, 0.2]
    template = np.r_[table, box]
    tree = cloud_tree(template)
    moved = template[::2] + [*rng.uniform(-0.2, 0.2, 2), 0.0] + rng.normal(0, 0.005, (1650, 3))
    constraint = pose_constraint(template, tree, moved, 0.04)
    found = best_slide(tree, template, moved, 0.04, constraint)

    first, second = (m / np.linalg.norm(m) for m in constraint.motions[3:, :SEARCHED_MOTIONS].T)
    second = second - (second @ first) * first
    second /= np.linalg.norm(second)
    lines = (first, second, (first + second) / np.sqrt(2), (first - second) / np.sqrt(2))
    steps = (*SLIDE_STEPS, *(-s for s in SLIDE_STEPS))
    offsets = np.array([s * rms_radius(moved) * line for line in lines for s in steps])
    offsets = np.r_[np.zeros((1, 3)), offsets]
    source, sampled = (c[:: max(1, len(c) // SEARCH_POINTS)] for c in (moved, template))
    both = np.stack(
        [
            overlap_fits(tree, source[None] + offsets[:, None], 0.04)[:, 0],
            overlap_fits(cloud_tree(moved), sampled[None] - offsets[:, None], 0.04)[:, 0],
        ],
        1,
    )
    gains = np.minimum((both[1:] - both[0]).min(1), both[1:].min(1) - both[0].min())
    if gains.max() <= 0:
        assert found.gain == 0.0
    else:
        np.testing.assert_allclose(found.offset, offsets[1 + int(np.argmax(gains))])
        assert found.gain > 0


@pytest.mark.parametrize(
    ("constraint", "slide_gain", "rule"),
    [
        (FREE_RATIO, 0.0, "correct"),  # the bound is pinned
        (0.99 * FREE_RATIO, 0.0, "free"),  # under it, free: uncertain
        (1.0, SLIDE_GAIN, "slid"),  # a slide that fits this much better: wrong
        (1.0, 0.99 * SLIDE_GAIN, "correct"),
    ],
)
def test_the_slide_rules_decide_at_their_bounds(constraint, slide_gain, rule):
    assert verdict_rule(1.0, 0.0, 0.0, constraint, slide_gain) == rule


def test_covered_shares_are_each_clouds_points_within_the_limit():
    """``covered_shares``: the source's and the template's share of all their points
    within the inlier distance of the other cloud, not of the overlap's."""
    from masknet.registration.judge.constraints import covered_shares
    from masknet.registration.judge.prepared import prepare_check

    template = _square(4000, (2.0, 1.0))
    half = template[template[:, 0] < 1.0]
    check = prepare_check(template, half, 0.04)
    np.testing.assert_allclose(covered_shares(check, np.eye(4)), [1.0, 0.5], atol=0.03)
    away = np.eye(4)
    away[2, 3] = 1.0  # lifted off the plane: nothing within the limit
    np.testing.assert_allclose(covered_shares(check, away), [0.0, 0.0])

"""The template's measured class (masknet.registration.judge.shape): closed shapes are
objects, surfaces seen from one side and scenes scanned from within are scans, in any
unit and at any point count."""

from __future__ import annotations

import numpy as np
import pytest

from masknet.registration.judge.shape import (
    SHAPE,
    ShapeTable,
    classify_template,
    one_sided_share,
    seen_from_inside,
)


def _sphere(count: int, rng: np.random.Generator) -> np.ndarray:
    points = rng.normal(size=(count, 3))
    return points / np.linalg.norm(points, axis=1, keepdims=True)


def _box(count: int, rng: np.random.Generator, low: float = -1.0) -> np.ndarray:
    """Points on the faces of the cube [low, 1]^3 (each point pushed onto one face)."""
    points = rng.uniform(low, 1.0, (count, 3))
    face = rng.integers(0, 3, count)
    side = np.where(rng.random(count) < 0.5, low, 1.0)
    points[np.arange(count), face] = side
    return points


def _shapes() -> dict[str, tuple[np.ndarray, str]]:
    rng = np.random.default_rng(0)
    sphere = _sphere(4000, rng)
    corner = rng.uniform(0, 1, (3000, 3))
    corner[np.arange(3000), rng.integers(0, 3, 3000)] = 0.0  # floor and two walls
    plane = np.c_[rng.uniform(-1, 1, (2000, 2)), 0.01 * rng.normal(size=2000)]
    return {
        "sphere": (sphere, "object"),
        "box": (_box(3000, rng), "object"),
        "sphere seen from one side": (sphere[sphere[:, 2] > 0.2], "scan"),
        "plane patch": (plane, "scan"),
        "room corner": (corner, "scan"),
    }


@pytest.mark.parametrize("name", list(_shapes()))
def test_closed_shapes_are_objects_and_one_sided_surfaces_scans(name):
    points, kind = _shapes()[name]
    found = classify_template(points)
    assert found.kind == kind, found
    # the class does not depend on the unit or on where the cloud lies
    moved = classify_template(1000.0 * points + [5e3, -2e3, 7e2])
    assert moved.kind == kind
    assert moved.one_sided == pytest.approx(found.one_sided, abs=0.02)


def test_the_one_sided_share_parts_the_two_kinds():
    """About 1 for a height field, 0.55-0.7 for closed shapes (the table's threshold
    between them)."""
    shapes = _shapes()
    closed = [one_sided_share(shapes[n][0]) for n in ("sphere", "box")]
    open_ = [one_sided_share(shapes[n][0]) for n in ("plane patch", "room corner")]
    assert max(closed) < SHAPE.scan_one_sided - 0.05 < min(open_) - 0.1, (closed, open_)
    assert min(open_) > 0.95


def test_a_room_scanned_from_within_is_a_scan():
    """A closed room whose samples thin out with the distance from a sensor at its centre:
    seen all round (not one-sided), yet a scan by the spacing's growth outwards; the same
    room sampled evenly reads as a closed object."""
    rng = np.random.default_rng(1)
    room = _box(60_000, rng) * [3.0, 2.0, 1.2]
    near = np.linalg.norm(room, axis=1)
    # a sensor's samples per area fall with the square of the distance and, as the walls
    # are seen more and more obliquely, faster: here with its cube
    scanned = room[rng.random(len(room)) < (near.min() / near) ** 3]
    even = room[rng.choice(len(room), len(scanned), replace=False)]
    assert seen_from_inside(scanned) >= SHAPE.scan_inside > seen_from_inside(even) + 0.2
    assert classify_template(scanned).kind == "scan"
    assert classify_template(even).kind == "object"


def test_large_clouds_cost_what_small_ones_do():
    """Every measure sees a seeded subset of ``points``: a cloud 40 times larger gets
    the same class and nearly the same share; repeated calls give the same value."""
    rng = np.random.default_rng(2)
    sphere = _sphere(40 * SHAPE.points, rng)
    assert one_sided_share(sphere) == one_sided_share(sphere)
    small = one_sided_share(sphere[: SHAPE.points])
    assert abs(one_sided_share(sphere) - small) < 0.05
    assert classify_template(sphere).kind == "object"


def test_the_table_sets_the_threshold():
    """A table whose one-sided threshold lies above 1 calls nothing one-sided."""
    plane = _shapes()["plane patch"][0]
    assert classify_template(plane).kind == "scan"
    never = ShapeTable(scan_one_sided=1.01, scan_one_sided_large=1.01, scan_inside=1.01)
    assert classify_template(plane, never).kind == "object"
    assert classify_template(plane, never, large=True).kind == "object"
    # a large template is a scan from a lower one-sided share
    between = ShapeTable(scan_one_sided=1.01, scan_one_sided_large=0.9)
    assert classify_template(plane, between, large=True).kind == "scan"


def test_tiny_clouds_read_as_one_sided():
    """Three points are a surface seen from one side (every view sees all of them)."""
    assert one_sided_share(np.eye(3)) == 1.0
    assert seen_from_inside(np.eye(3)) == 0.0

"""``auto``'s route by what the clouds are (stage 1 of masknet.registration.stages.auto):
a 1,500-point fragment of a real room scan takes the scans' consensus front end, a
20,000-point closed object the objects' fast path, whatever their point counts say."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from masknet import register
from masknet.data import bundled_sample_path, load_modelnet40
from masknet.evaluation.registration import pose_errors
from masknet.geometry.knn import cloud_tree
from masknet.registration.judge.shape import classify_template

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def room_fragments(scans_dir, o3d):
    """A fragment of each room scan about one place: the nearest quarter of room_scan1's
    points to one of its points (1,500 of them kept) and of room_scan2's to the same place
    under the robot's odometry (1,200 kept); room_scan2 as it was given."""
    from masknet.experiments.real_pairs import room_odometry
    from masknet.experiments.scans import load_pair
    from masknet.geometry.se3 import transform_points

    first, second, _ = load_pair(scans_dir, "room_scan1.pcd", "room_scan2.pcd", None)
    rng = np.random.default_rng(0)
    centre = first[rng.integers(len(first))]
    near = cloud_tree(first).query(centre[None], k=len(first) // 4)[1][0]
    template = first[rng.choice(near, 1500, replace=False)]
    moved = transform_points(room_odometry(), second)
    near = cloud_tree(moved).query(centre[None], k=len(second) // 4)[1][0]
    return template, second[rng.choice(near, 1200, replace=False)]


def test_a_room_fragment_of_1500_points_takes_the_scans_path(room_fragments):
    """Between the sparse and the scans' sizes a template is measured once the fast path
    has not held; a scan's goes on to the consensus front end (the search's answer may
    still win, judged by the verdict)."""
    template, source = room_fragments
    assert classify_template(template).kind == "scan"
    result = register(template, source)
    assert result.times["route"] > 0 and result.times["consensus"] > 0
    assert str(result.info["path"]) in ("consensus", "robust/consensus", "robust/search")


def _dense_object(count: int) -> np.ndarray:
    """A bundled ModelNet40 shape (a bathtub, closed) densified to ``count`` points: each
    point repeated, jittered along the surface by a tenth of the shape's spacing."""
    shape = np.asarray(load_modelnet40(bundled_sample_path()).points[3], np.float64)
    rng = np.random.default_rng(1)
    dense = np.repeat(shape, -(-count // len(shape)), axis=0)[:count]
    return dense + 0.005 * rng.normal(size=dense.shape)


def test_a_20000_point_object_takes_the_objects_path():
    """Over ``consensus_from`` points, yet closed: measured before anything runs, and
    then the objects' path: the fast path (MaskNet, ICP) and, where its fit falls short
    of the objects' accept level, the search; no consensus front end."""
    template = _dense_object(20_000)
    assert classify_template(template, large=True).kind == "object"
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_euler("z", 20, degrees=True).as_matrix()
    turn[:3, 3] = [0.1, -0.05, 0.02]
    rng = np.random.default_rng(2)
    source = template[rng.choice(len(template), 12_000, replace=False)] @ turn[:3, :3].T
    source += turn[:3, 3]
    result = register(template, source)
    assert "consensus" not in result.times and result.times["route"] > 0
    assert str(result.info["path"]) in ("fast", "robust/correspondences", "robust/search")
    truth = np.linalg.inv(turn)
    assert pose_errors(result.transform[None], truth[None])[0][0] < 1.0


def test_the_same_object_as_a_scan_would_take_the_front_end(monkeypatch):
    """The route follows the measure: the same pair with a table that calls everything
    one-sided goes through the consensus front end first."""
    from masknet.registration.judge import shape

    template = _dense_object(20_000)
    never_closed = shape.ShapeTable(scan_one_sided=0.0, scan_one_sided_large=0.0)
    monkeypatch.setattr(shape, "SHAPE", never_closed)
    monkeypatch.setattr(
        "masknet.registration.stages.route.classify_template",
        lambda t, large=False: shape.classify_template(t, never_closed, large),
    )
    result = register(template, template[:12_000] + [0.01, 0.0, 0.0])
    assert result.times["consensus"] > 0

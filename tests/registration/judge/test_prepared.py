"""masknet.registration.judge.prepared: a pair prepared once (even subsets, which points count)."""

from __future__ import annotations

import numpy as np
import pytest

from masknet.geometry.clouds import median_spacing
from masknet.geometry.knn import cloud_tree
from masknet.registration.judge import prepared
from masknet.registration.judge.fit import pose_fit
from masknet.registration.judge.prepared import (
    PreparedPair,
    check_points,
    fit_clouds,
    isolated_free,
    prepare_check,
    surface_points,
)


def test_isolated_points_are_found_and_a_sparse_cloud_keeps_all():
    rng = np.random.default_rng(0)
    surface = np.c_[rng.uniform(0, 1, (500, 2)), np.zeros(500)]
    stray = rng.uniform(5, 9, (20, 3))
    keep = isolated_free(np.concatenate([surface, stray]), 0.2)
    assert keep[:500].all() and not keep[500:].any()
    assert isolated_free(rng.uniform(0, 100, (50, 3)), 0.01).all()


def test_a_close_pair_of_outliers_is_no_surface_with_two_neighbours_asked():
    """Two stray points 0.1 apart keep each other at one neighbour, not at two (the
    check of auto's fast path and of robust's early exit); the surface keeps both."""
    rng = np.random.default_rng(0)
    surface = np.c_[rng.uniform(0, 1, (500, 2)), np.zeros(500)]
    pair = np.array([[5.0, 5, 5], [5.1, 5, 5]])
    cloud = np.concatenate([surface, pair])
    one, two = isolated_free(cloud, 0.2), isolated_free(cloud, 0.2, neighbours=2)
    assert one[500:].all() and not two[500:].any()
    assert one[:500].all() and two[:500].all()
    got = surface_points(cloud, 0.2)
    assert all((a == b).all() for a, b in zip(got[:2], (one, two), strict=True))
    assert got[2].all()  # no spacing given: no point is a stray


def test_a_stray_point_beside_a_surface_is_dropped_and_an_edge_is_not():
    """A point 0.08 above a plane sampled 0.04 apart has plane points for its
    neighbours (so the neighbour test keeps it), but no point within the fit's 1.5
    spacings and lies off their plane: the check drops it. The points along the fold of
    an L-shaped surface lie off their neighbours' plane too, but close to other points:
    they stay (a wrong pose misfits edges first)."""
    rng = np.random.default_rng(0)
    u, v = np.meshgrid(np.arange(0.02, 1, 0.04), np.arange(0.02, 1, 0.04))
    floor = np.c_[u.ravel(), v.ravel(), np.zeros(u.size)]  # an even grid, as prepared
    u, w = np.meshgrid(np.arange(0.02, 1, 0.04), np.arange(0.04, 0.5, 0.04))
    wall = np.c_[u.ravel(), np.zeros(u.size), w.ravel()]
    surface_count = len(floor) + len(wall)
    a, b = np.meshgrid(np.linspace(0.2, 0.8, 5), [0.4, 0.7])  # 0.15 apart at least
    stray = np.c_[a.ravel(), b.ravel(), np.full(10, 0.08)]
    cloud = np.concatenate([floor, wall, stray]) + rng.normal(0, 0.003, (surface_count + 10, 3))
    spacing = median_spacing(floor)
    surface, strict, attached = surface_points(cloud, 0.2, spacing)
    assert surface.all() and strict.all()
    assert not attached[surface_count:].any() and attached[:surface_count].all()
    kept = check_points(surface, strict, attached)
    assert not kept[surface_count:].any() and kept[:surface_count].all()
    # Without a spacing nothing is a stray.
    assert surface_points(cloud, 0.2)[2].all()
    # More than CHECK_MAX_DROP of the points counted as strays are a part of the cloud,
    # not strays: the check keeps them all.
    assert check_points(surface, strict, np.zeros(len(cloud), bool)).all()


def test_the_check_keeps_a_sparse_part_of_a_surface_that_is_more_than_a_few_points():
    """Stray pairs are dropped from the check; a sparse part (points in pairs 0.15 apart,
    0.5 between pairs: one neighbour each within 0.2) that is over 5% of the cloud is kept:
    it may be the part a wrong pose misfits."""
    rng = np.random.default_rng(0)
    dense = np.c_[rng.uniform(0, 1, (500, 2)), np.zeros(500)]
    pair = np.array([[5.0, 5, 5], [5.1, 5, 5]])
    few = np.concatenate([dense, pair])
    surface = isolated_free(few, 0.2)
    assert check_points(surface, isolated_free(few, 0.2, neighbours=2)).sum() == 500
    starts = 3 + 0.5 * np.arange(30)
    sparse = np.c_[np.sort(np.r_[starts, starts + 0.15]), np.zeros((60, 2))]
    many = np.concatenate([dense, sparse])
    surface = isolated_free(many, 0.2)
    assert surface[500:].all() and not isolated_free(many, 0.2, neighbours=2)[500:].any()
    assert (check_points(surface, isolated_free(many, 0.2, neighbours=2)) == surface).all()


def test_a_prepared_pair_is_even_where_a_random_subset_keeps_the_scanners_crowd():
    """A room-like pair: a floor crowded at the scanner's feet (a tenth of the area, nine
    tenths of the points) and walls. The prepared source keeps the crowd's share near its
    area's; the fit on it ranks the right pose above the identity, which keeps the two
    scanners' crowds together."""
    rng = np.random.default_rng(0)

    def scan(centre: np.ndarray) -> np.ndarray:
        feet = centre[:2] + rng.normal(0, 0.5, (18_000, 2))
        floor = np.c_[np.concatenate([feet, rng.uniform(-5, 5, (2_000, 2))]), np.zeros(20_000)]
        u, h = rng.uniform(-5, 5, 4_000), rng.uniform(0, 3, 4_000)
        walls = [np.c_[u, np.full(4_000, side), h] for side in (-5, 5)]
        walls += [np.c_[np.full(4_000, side), u, h] for side in (-5, 5)]
        return np.concatenate([floor, *walls])

    template = scan(np.zeros(3))
    shift = np.array([2.0, 1.0, 0.0])
    source = scan(shift) - shift  # the second scanner stands at the origin of its frame
    truth = np.eye(4)
    truth[:3, 3] = shift
    pair = fit_clouds(template, source, fine_points=2048)
    crowd = np.linalg.norm(pair.source[:, :2], axis=1) < 1.0
    assert len(pair.source) <= 2048 and len(pair.template) <= 8 * 2048
    assert crowd.mean() < 0.2  # 18,000 of 36,000 input points lie there
    limit = 1.5 * pair.spacing
    right = pose_fit(pair.tree, pair.source, truth, limit).score
    wrong = pose_fit(pair.tree, pair.source, np.eye(4), limit).score
    assert right > wrong + 0.2
    assert pose_fit(pair.tree, pair.source, truth, limit).fitness > 0.8
    # A random subset against the whole template, at the whole template's spacing,
    # counts the other way: only the crowd is dense enough to fit, and the identity
    # lays one crowd on the other.
    few = source[np.random.default_rng(1).choice(len(source), 2048, replace=False)]
    tree = cloud_tree(template)
    crowded = 1.5 * median_spacing(template, tree)
    assert pose_fit(tree, few, np.eye(4), crowded).fitness > 0.45
    assert pose_fit(tree, few, truth, crowded).fitness < 0.3


def test_a_small_pair_is_prepared_whole():
    rng = np.random.default_rng(0)
    template, source = rng.normal(size=(500, 3)), rng.normal(size=(300, 3))
    pair = fit_clouds(template, source, fine_points=4096)
    assert (pair.template == template).all() and (pair.source == source).all()


def test_a_source_thinner_than_its_template_has_no_strays_at_its_edges():
    """A source drawn at random from an L-shaped template twenty times denser (as a scan's
    subset is) has gaps of several template spacings everywhere; its points count as
    strays only beyond its own spacing, so the fold and the gaps stay in the check."""
    rng = np.random.default_rng(0)
    u, v = np.meshgrid(np.arange(0, 4, 0.01), np.arange(0, 4, 0.01))
    floor = np.c_[u.ravel(), v.ravel(), np.zeros(u.size)]
    wall = np.c_[rng.uniform(0, 4, 40_000), np.zeros(40_000), rng.uniform(0, 2, 40_000)]
    template = np.concatenate([floor, wall])
    source = template[rng.choice(len(template), 4096, replace=False)]
    pair = fit_clouds(template, source, 4096)
    assert (~pair.attached).mean() < 0.005


def _counted(monkeypatch, module, name: str) -> list:
    """Replace ``module.name`` by a wrapper that counts its calls: the list of calls."""
    calls: list = []
    original = getattr(module, name)

    def counting(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(module, name, counting)
    return calls


@pytest.fixture
def scan_like_pair():
    """A ModelNet40 pair of the bundled sample (1,024 points), turned up to 45 degrees."""
    from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs

    shapes = load_modelnet40(bundled_sample_path()).points
    pairs = make_test_pairs(shapes, 1, PairConfig(max_angle_deg=45), seed=4)
    return pairs.template[0].double().numpy(), pairs.source[0].double().numpy()


def test_every_view_of_the_pair_is_computed_once_per_call(scan_like_pair, o3d, monkeypatch):
    """A call through every stage of ``auto`` (the pair taken as a scan's, the consensus
    never settling, so that the front end, the fast path, the search and the scans'
    verdict all run) builds the fit's view once, the front end's grids and their verdict
    view once, never the whole pair's verdict view, and takes the consensus answer's
    tree and cut-off from the check's view."""
    from masknet import register
    from masknet.registration.judge import arbiter
    from masknet.registration.stages import auto, consensus
    from masknet.registration.terms.options import RobustOptions

    template, source = scan_like_pair
    fits = _counted(monkeypatch, prepared, "fit_clouds")
    grids = _counted(monkeypatch, consensus, "_grids")
    grid_checks = _counted(monkeypatch, consensus, "prepare_check")
    pair_checks = _counted(monkeypatch, prepared, "prepare_check")
    grid_trees = _counted(monkeypatch, consensus, "cloud_tree")
    judged = _counted(monkeypatch, auto, "judge")
    monkeypatch.setattr(arbiter, "settles", lambda check: False)
    monkeypatch.setattr(arbiter, "may_compete", lambda check: True)
    monkeypatch.setattr(arbiter, "accepts", lambda fitness, accept: False)
    options = RobustOptions(consensus_from=512, consensus_below=256)
    result = register(template, source, method="auto", options=options)
    assert str(result.info["path"]).startswith("robust/"), result.info["path"]
    assert len(judged) == 1  # the scans' verdict on the search's answer ran
    assert (len(fits), len(grids), len(grid_checks)) == (1, 1, 1)
    assert pair_checks == [] and grid_trees == []


def test_a_call_without_the_front_end_never_builds_its_grids(scan_like_pair, monkeypatch):
    """An object pair: the fast path and the search share the one fit view."""
    from masknet import register
    from masknet.registration.judge import arbiter
    from masknet.registration.stages import consensus

    template, source = scan_like_pair
    fits = _counted(monkeypatch, prepared, "fit_clouds")
    grids = _counted(monkeypatch, consensus, "_grids")
    monkeypatch.setattr(arbiter, "accepts", lambda fitness, accept: False)
    result = register(template, source)
    assert str(result.info["path"]).startswith("robust/"), result.info["path"]
    assert len(fits) == 1 and grids == []


def test_a_view_is_built_once_even_when_it_is_none():
    pair = PreparedPair(np.zeros((4, 3)), np.zeros((4, 3)), 16)
    built: list = []

    def build():
        built.append(1)

    assert pair.view("grids", build) is None and pair.view("grids", build) is None
    assert built == [1]


def test_the_verdict_on_the_prepared_pair_is_the_verdict_from_scratch(scan_like_pair):
    """The verdict view of a pair whose fit view was computed first judges as
    ``assess_registration`` and a fresh ``prepare_check`` do, field for field; the
    consensus grids' verdict view as a fresh one of the same grids."""
    from masknet import assess_registration
    from masknet.registration.judge.assessment import judge

    template, source = scan_like_pair
    rng = np.random.default_rng(2)
    pair = PreparedPair(template, source, 4096)
    assert pair.fit is pair.fit  # one fit view
    for shift in (0.0, 0.05, 0.3):
        pose = np.eye(4)
        pose[:3, 3] = rng.normal(size=3) * shift
        kept = judge(pair.check(), pose)
        assert pair.check() is pair.check()
        assert kept == judge(prepare_check(template, source), pose)
        assert kept == assess_registration(template, source, pose)
        given = judge(pair.check(0.05), pose)
        assert given == assess_registration(
            template, source, pose, max_correspondence_distance=0.05
        )


def test_the_front_ends_verdict_view_is_a_fresh_one_of_its_grids(scan_like_pair, o3d):
    from masknet.registration.judge.assessment import judge
    from masknet.registration.stages.consensus import consensus_grids, consensus_register
    from masknet.registration.terms.options import RobustOptions

    template, source = scan_like_pair
    pair = PreparedPair(template, source, 4096)
    found = consensus_register(template, source, RobustOptions(), {}, "first", pair)
    grids = consensus_grids(pair, RobustOptions())
    fresh = prepare_check(grids.template_grid, grids.source_grid, open3d=True, even=False)
    assert judge(grids.check, found.pose) == judge(fresh, found.pose) == found.check
    tree, limit = grids.template_fit()
    assert tree is grids.check.tree and limit == 1.5 * median_spacing(
        grids.template_grid, sample=2048
    )
    consensus_register(template, source, RobustOptions(), {}, "first", pair)
    assert consensus_grids(pair, RobustOptions()) is grids  # the pair's view, not a second one

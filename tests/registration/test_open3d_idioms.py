"""Open3D's idioms give what masknet's own spelling gives, for every method of the table:
``init`` as a (4, 4) matrix, Open3D point clouds (legacy and tensor) as inputs,
``max_correspondence_distance`` and ``max_iteration`` (ICPConvergenceCriteria's name); through
``register`` and through ``masknet register``."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from masknet import MaskNetError, register
from masknet.cli import main
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.geometry.se3 import transform_points
from masknet.registration.terms.methods import METHOD_TABLE, PIPELINES

o3d = pytest.importorskip("open3d")

# Open3D's RANSAC is not repeatable between calls (RESULTS, "Repeatability of Open3D's
# RANSAC"), and FGR's features round differently on the moved coordinates on some CPUs
# (3e-4 with AVX-512, 1e-7 without): both compare within a tolerance that still tells a
# wrong start apart.
TOLERANCE = {"open3d-ransac": 1e-3, "open3d-fgr": 1e-3}


@pytest.fixture(scope="module")
def pair() -> tuple[np.ndarray, np.ndarray]:
    shapes = load_modelnet40(bundled_sample_path(), "test").points[:1]
    pairs = make_test_pairs(shapes, 1, PairConfig(), seed=2)
    return pairs.template[0].double().numpy(), pairs.source[0].double().numpy()


@pytest.fixture(scope="module")
def start() -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("zyx", [20, -10, 5], degrees=True).as_matrix()
    pose[:3, 3] = [0.1, -0.2, 0.05]
    return pose


def _same(method: str, a: np.ndarray, b: np.ndarray) -> None:
    np.testing.assert_allclose(a, b, atol=TOLERANCE.get(method, 1e-9))


def _masknet_spelling_of_start(method: str) -> dict:
    """What ``init=matrix`` means in masknet's own words, for the source moved by it."""
    return {} if method in PIPELINES or not METHOD_TABLE[method].uses_init else {"init": "identity"}


@pytest.mark.parametrize("method", list(METHOD_TABLE))
def test_init_as_a_matrix_starts_the_method_there(method, pair, start):
    template, source = pair
    given = register(template, source, method=method, init=start)
    moved = register(
        template,
        transform_points(start, source),
        method=method,
        **_masknet_spelling_of_start(method),
    )
    _same(method, given.transform, moved.transform @ start)
    assert given.transform.shape == (4, 4)
    if given.rounds:
        _same(method, given.rounds[-1], given.transform)


@pytest.mark.parametrize("method", list(METHOD_TABLE))
def test_open3d_point_clouds_are_taken_as_their_points(method, pair):
    template, source = pair
    legacy = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(template))
    tensor = o3d.t.geometry.PointCloud(o3d.core.Tensor(source))
    _same(
        method,
        register(legacy, tensor, method=method).transform,
        register(template, source, method=method).transform,
    )


def _fields(method: str) -> set[str]:
    return {f.name for f in dataclasses.fields(METHOD_TABLE[method].options)}


@pytest.mark.parametrize(
    "method",
    [m for m in METHOD_TABLE if _fields(m) & {"max_correspondence_distance", "max_iterations"}],
)
def test_open3d_option_names_mean_masknets(method, pair):
    template, source = pair
    fields = _fields(method)
    ours, theirs = {}, {}
    if "max_correspondence_distance" in fields:
        ours["max_correspondence_distance"] = theirs["max_correspondence_distance"] = 0.2
    # Open3D's ICP cap; the pipelines' own max_iterations is another thing: refused there.
    icp_cap = "max_iterations" in fields and method not in PIPELINES
    if icp_cap:
        ours["max_iterations"], theirs["max_iteration"] = 4, 4
    expected = register(
        template, source, method=method, options=METHOD_TABLE[method].options(**ours)
    )
    _same(method, register(template, source, method=method, **theirs).transform, expected.transform)
    if method in PIPELINES:
        with pytest.raises(MaskNetError, match='max_iteration .*method="icp"'):
            register(template, source, method=method, max_iteration=4)
    if icp_cap:
        with pytest.raises(MaskNetError, match="not both"):
            register(template, source, method=method, max_iterations=4, max_iteration=4)


def test_a_batch_of_starts_and_bad_starts(pair, start):
    template, source = pair
    batch = register(
        np.stack([template, template]),
        np.stack([source, source]),
        method="icp",
        init=np.stack([np.eye(4), start]),
    )
    one = register(template, source, method="icp", init=start)
    # A batch runs torch's ICP, one pair the KD-tree loop: the same answer to float32's digits.
    np.testing.assert_allclose(batch.transform[1], one.transform, atol=1e-6)
    for bad, match in (
        (np.eye(3), "4, 4"),
        ("middle", "unknown init"),
        (np.full((4, 4), np.nan), "NaN"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "rigid"),
    ):
        with pytest.raises(MaskNetError, match=match):
            register(template, source, method="icp", init=bad)


@pytest.mark.parametrize("method", list(METHOD_TABLE))
def test_the_cli_takes_init_as_a_matrix_file_and_the_cut_off(method, pair, start, tmp_path):
    template, source = pair
    np.savetxt(tmp_path / "template.xyz", template, fmt="%.17g")
    np.save(tmp_path / "source.npy", source)
    np.savetxt(tmp_path / "start.txt", start, fmt="%.17g", header="a start")
    args = ["register", str(tmp_path / "template.xyz"), str(tmp_path / "source.npy")]
    args += ["-o", str(tmp_path / "moved.xyz"), "--method", method, "--exit-zero"]
    args += ["--init", str(tmp_path / "start.txt")]
    fields = _fields(method)
    options = {}
    if "max_correspondence_distance" in fields:
        args += ["--max-correspondence-distance", "0.2"]
        options["max_correspondence_distance"] = 0.2
    assert main(args) == 0
    written = np.loadtxt(tmp_path / "moved_transform.txt")
    expected = register(template, source, method=method, init=start, **options).transform
    np.testing.assert_allclose(written, expected, atol=max(TOLERANCE.get(method, 0), 1e-8))


def test_every_entry_point_takes_open3d_clouds(pair):
    import masknet

    template, source = pair
    legacy = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(template))
    tensor = o3d.t.geometry.PointCloud(o3d.core.Tensor(source))
    pose = register(template, source).transform
    assert (
        masknet.assess_registration(legacy, tensor, pose).verdict
        == masknet.assess_registration(template, source, pose).verdict
    )
    quality = masknet.evaluate_registration(template=legacy, source=tensor, transform=pose)
    assert (
        quality.fitness
        == masknet.evaluate_registration(template=template, source=source, transform=pose).fitness
    )
    net = masknet.MaskNet.pretrained()
    np.testing.assert_array_equal(net.predict(legacy, tensor), net.predict(template, source))
    moved = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(transform_points(pose, source)))
    np.testing.assert_array_equal(
        masknet.denoise(legacy, moved).mask,
        masknet.denoise(template, transform_points(pose, source)).mask,
    )

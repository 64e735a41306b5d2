"""Units: every method gives the same result for a real pair in metres and the same pair
in millimetres (the 3DMatch pair of ../shared/data/scans, 2,000 points a side), because
``register`` runs in one unit-free frame (:class:`masknet.geometry.clouds.Frame`)."""

from __future__ import annotations

import numpy as np
import pytest

from masknet import register
from masknet.evaluation.registration import pose_errors
from masknet.registration.terms.methods import METHODS

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


# Mixed units: the one-line diagnosis (masknet.registration.terms.units).
REAL_PAIRS = {
    "3DMatch": ("geotransformer_demo_ref.npy", "geotransformer_demo_src.npy"),
    "3DMatch (Open3D)": ("o3d_feature_cloud_bin_0.pcd", "o3d_feature_cloud_bin_1.pcd"),
    "rooms": ("room_scan1.pcd", "room_scan2.pcd"),
    "carton in its scene": ("milk.pcd", "milk_cartoon_all_small_clorox.pcd"),
}


@pytest.fixture(scope="module")
def real_pairs(scans_dir) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    from masknet.io import read_points

    def load(name: str) -> np.ndarray:
        path = scans_dir / name
        return np.load(path) if path.suffix == ".npy" else read_points(path, drop_nonfinite=True)

    return {name: (load(a), load(b)) for name, (a, b) in REAL_PAIRS.items()}


def test_real_pairs_and_subsampled_ones_are_one_unit(real_pairs):
    from masknet.registration.terms.units import check_units

    rng = np.random.default_rng(0)
    for name, (template, source) in real_pairs.items():
        eighth = rng.permutation(len(source))[: len(source) // 8]
        eighth_t = rng.permutation(len(template))[: len(template) // 8]
        for label, (t, s) in {
            "as given": (template, source),
            "source subsampled 8x": (template, source[eighth]),
            "template subsampled 8x": (template[eighth_t], source),
        }.items():
            check = check_units(t, s)
            assert not check.mixed, (name, label, check)


@pytest.mark.parametrize("factor", [10, 100, 1000])
def test_mixed_units_get_one_line_naming_the_factor(real_pairs, factor):
    from masknet.registration.terms.units import check_units

    for name, (template, source) in real_pairs.items():
        cases = {"source": (template, factor * source), "template": (factor * template, source)}
        for larger, (t, s) in cases.items():
            check = check_units(t, s)
            if name == "carton in its scene" and larger == "template" and factor == 10:
                # The blind spot: the scene then spans about what its object does.
                assert not check.mixed
                continue
            assert check.mixed, (name, larger, factor, check)
            assert f"the {larger}'s point spacing" in check.message
            assert f"about {factor:,}x" in check.message


def test_register_assess_and_the_cli_say_it_before_any_work(tmp_path, capsys):
    from masknet import MaskNetWarning, assess_registration
    from masknet.cli import main
    from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs

    shapes = load_modelnet40(bundled_sample_path(), "test").points[:1]
    pair = make_test_pairs(shapes, 1, PairConfig(), seed=5)
    metres, source = pair.template[0].double().numpy(), pair.source[0].double().numpy()
    millimetres = 1000 * metres
    with pytest.warns(MaskNetWarning, match="different units.*about 1,000x"):
        register(millimetres, source, method="icp")
    with pytest.warns(MaskNetWarning, match="different units"):
        assess_registration(millimetres, source, np.eye(4))
    np.savetxt(tmp_path / "template_mm.xyz", millimetres)
    np.save(tmp_path / "source_m.npy", source)
    args = ["register", str(tmp_path / "template_mm.xyz"), str(tmp_path / "source_m.npy")]
    main([*args, "-o", str(tmp_path / "moved.xyz"), "--method", "icp", "--exit-zero"])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "different units" in line]
    assert len(lines) == 1 and lines[0].startswith("masknet: warning: the clouds look like")
    # one unit: no line
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", MaskNetWarning)
        register(metres, source, method="icp")

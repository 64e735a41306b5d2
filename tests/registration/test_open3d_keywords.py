"""Open3D's keywords and masknet's spellings of them, through ``register`` and ``masknet
register``: the same words run the same method to the same transform, or are refused in one
line naming the method that takes them. None changes the method without saying so."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from masknet import MaskNetError, register
from masknet.cli import main
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.errors import MaskNetWarning
from masknet.evaluation.registration import pose_errors
from masknet.registration.terms.options import RobustOptions

SCANS = Path(__file__).resolve().parents[3] / "shared" / "data" / "scans"

# Python keywords, the same words on the command line, and what they must give: the method
# that runs with the keywords it must equal, or the refusal's words.
AUTO = ({}, "auto")
CUT = ({"options": RobustOptions(max_correspondence_distance=0.2)}, "auto")
ICP30 = ({"method": "icp", "max_iterations": 30}, "icp")
ICP_IDENTITY = ({"method": "icp", "init": "identity"}, "icp")
ICP_MASK = ({"method": "icp", "mask_threshold": 0.5}, "icp")
REFUSED_ICP = 'applies to method="icp"'
CASES = [
    ({}, [], AUTO),
    ({"max_correspondence_distance": 0.2}, ["--max-correspondence-distance", "0.2"], CUT),
    ({"init": np.eye(4)}, [], AUTO),
    ({"init": "identity"}, ["--init", "identity"], AUTO),
    ({"init": None}, [], AUTO),
    ({"init": "centroid"}, ["--init", "centroid"], AUTO),
    ({"max_iteration": 30}, [], "max_iteration .*" + REFUSED_ICP),
    ({"max_iterations": 30}, ["--max-iterations", "30"], "max_iterations .*" + REFUSED_ICP),
    ({"mask_threshold": 0.5}, ["--mask-threshold", "0.5"], "mask_threshold .*" + REFUSED_ICP),
    ({"threshold": 0.5}, ["--threshold", "0.5"], "max_correspondence_distance.*" + REFUSED_ICP),
    ({"k": 300}, ["--k", "300"], "k .*" + REFUSED_ICP),
    ({"refine_iterations": 5}, ["--refine", "5"], r'refines itself.*method=\\?"icp"'),
    ({"relative_rmse": 1e-6}, ["--option", "relative_rmse=1e-6"], 'applies to method="icp"'),
    # Named: the rounds' method takes every spelling of the same words.
    ({"method": "icp", "max_iteration": 30}, ["--method", "icp", "--max-iterations", "30"], ICP30),
    ({"method": "icp", "init": np.eye(4)}, ["--method", "icp", "--init", "identity"], ICP_IDENTITY),
    ({"method": "icp", "threshold": 0.5}, ["--method", "icp", "--threshold", "0.5"], ICP_MASK),
    ({"method": "auto", "max_iterations": 4}, ["--method", "auto", "--max-iterations", "4"],
     ({"options": RobustOptions(max_iterations=4)}, "auto")),
]  # fmt: skip
SHOWN = {"auto": "default pipeline (auto)", "icp": "Mask-ICP"}


@pytest.fixture(scope="module")
def pair(tmp_path_factory) -> tuple[np.ndarray, np.ndarray, Path]:
    shapes = load_modelnet40(bundled_sample_path(), "test").points[:1]
    pairs = make_test_pairs(shapes, 1, PairConfig(), seed=2)
    template, source = pairs.template[0].double().numpy(), pairs.source[0].double().numpy()
    folder = tmp_path_factory.mktemp("pair")
    np.save(folder / "template.npy", template)
    np.save(folder / "source.npy", source)
    return template, source, folder


def _python(template: np.ndarray, source: np.ndarray, keywords: dict):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # threshold=: checked below
        return register(template, source, **keywords)


@pytest.mark.parametrize(("keywords", "flags", "expected"), CASES)
def test_the_same_words_run_the_same_method_or_are_refused(
    keywords, flags, expected, pair, one_thread, tmp_path, capsys
):
    template, source, folder = pair
    out = tmp_path / "moved.npy"
    argv = ["register", str(folder / "template.npy"), str(folder / "source.npy")]
    argv += ["-o", str(out), "--exit-zero", *flags]
    if isinstance(expected, str):  # refused, in Python and on the command line alike
        with pytest.raises(MaskNetError, match=expected) as caught:
            _python(template, source, keywords)
        assert "\n" not in str(caught.value)
        if flags:
            assert main(argv) == 2
            err = capsys.readouterr().err
            assert err.count("error:") == 1 and "Traceback" not in err
            assert not out.exists()
        return
    reference, method = expected
    wanted = register(template, source, **reference)
    given = _python(template, source, keywords)
    assert given.method == wanted.method == method
    np.testing.assert_allclose(given.transform, wanted.transform, atol=1e-9)
    if keywords and not flags:
        return  # a Python value (a matrix, None) with no command-line spelling
    assert main(argv) == 0
    assert SHOWN[method] in capsys.readouterr().out
    np.testing.assert_allclose(
        np.loadtxt(tmp_path / "moved_transform.txt"), wanted.transform, atol=1e-8
    )


def test_the_former_threshold_says_what_it_is_now(pair, capsys, tmp_path):
    template, source, folder = pair
    with pytest.warns(DeprecationWarning, match="mask_threshold=.*max_correspondence_distance="):
        register(template, source, method="icp", threshold=0.5)
    argv = ["register", str(folder / "template.npy"), str(folder / "source.npy"), "--exit-zero"]
    assert (
        main([*argv, "-o", str(tmp_path / "m.npy"), "--method", "icp", "--threshold", "0.5"]) == 0
    )
    assert "--threshold is deprecated; it is --mask-threshold" in capsys.readouterr().err
    with pytest.raises(MaskNetError, match="give mask_threshold only"):
        register(template, source, method="icp", threshold=0.5, mask_threshold=0.5)


@pytest.mark.skipif(not (SCANS / "geotransformer_demo_ref.npy").exists(), reason="no scans")
def test_the_cut_off_on_the_3dmatch_pair_keeps_the_default_and_says_where_unused():
    ref, src, truth = (
        np.load(SCANS / f"geotransformer_demo_{n}.npy") for n in ("ref", "src", "gt")
    )
    with pytest.warns(MaskNetWarning, match="max_correspondence_distance was not used"):
        result = register(ref, src, max_correspondence_distance=0.05)
    assert result.method == "auto"
    rotation_error = pose_errors(result.transform[None], truth[None])[0][0]
    assert rotation_error < 1.0  # the default's 0.56 degrees; Mask-ICP ended 16.9 off

"""The README's Python examples run as written, on a pair from the bundled sample."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs

README = Path(__file__).resolve().parents[1] / "README.md"


def _python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)


def test_the_readme_has_python_examples():
    blocks = _python_blocks()
    assert len(blocks) >= 3 and any("register(" in b for b in blocks)


@pytest.mark.parametrize("index", range(len(_python_blocks())))
def test_readme_python_example_runs(index, small_masknet, one_thread):
    shapes = load_modelnet40(bundled_sample_path(), "test").points[:1]
    pair = make_test_pairs(shapes, 1, PairConfig(), seed=3)
    template, source = pair.template[0].double().numpy(), pair.source[0].double().numpy()
    noisy = make_test_pairs(
        shapes, 1, PairConfig(max_angle_deg=0, max_translation=0, outlier_ratio=0.1), seed=4
    )
    namespace = {
        "template": template,
        "source": source,
        "noisy_scan": noisy.source[0].double().numpy(),
        "clean_template": noisy.template[0].double().numpy(),
        "my_denoiser": small_masknet,
    }
    block = _python_blocks()[index]
    if "kinect_scene" in block:  # an object among four others, three radii apart
        all_shapes = load_modelnet40(bundled_sample_path(), "test").points[:5].astype(float)
        grid = np.array([[0, 0, 0], [3, 0, 0], [0, 3, 0], [3, 3, 0], [6, 0, 0]], float)
        namespace["carton"] = all_shapes[2]
        namespace["kinect_scene"] = np.concatenate(all_shapes + grid[:, None])
    exec(compile(block, f"README.md python block {index}", "exec"), namespace)
    if "object_points" in namespace:  # the object found where it was put
        expected = namespace["carton"].mean(0) + [0, 3, 0]
        np.testing.assert_allclose(namespace["object_points"].mean(0), expected, atol=0.02)
    # Whatever the block produced has the documented shapes.
    if "mask" in namespace:
        assert namespace["mask"].shape == (len(template),)
    if "result" in namespace:
        assert namespace["result"].transform.shape == (4, 4)
        assert np.isfinite(namespace["result"].transform).all()
    if "paper" in namespace and "robust" in namespace:  # the registration block
        from masknet.evaluation.registration import pose_errors

        truth = pair.transform[0].double().numpy()[None]
        for name in ("result", "robust"):
            rot, trans = pose_errors(namespace[name].transform[None], truth)
            assert rot[0] < 0.5 and trans[0] < 0.01, name  # a clean pair, rightly registered
        assert str(namespace["result"].info["path"]) in ("fast", "robust/correspondences")
        assert not namespace["result"].info["ambiguous"]
    if "quality" in namespace:  # a correct result on a clean pair lies on the template
        assert 0.95 < namespace["quality"].fitness <= 1
        assert namespace["quality"].inlier_rmse < namespace["quality"].max_distance
    if "covered" in namespace:  # the refined loop: three rounds, masks at the pose returned
        loop = namespace["result"]
        assert len(loop.rounds) == 3 and loop.source_mask.shape == (len(source),)
        truth = pair.mask[0].numpy()
        assert (loop.mask & truth).sum() / loop.mask.sum() >= 0.9
        assert len(namespace["rule"].rounds) == 3
    if "kept" in namespace:
        assert namespace["kept"].mask.shape == (len(namespace["noisy_scan"]),)

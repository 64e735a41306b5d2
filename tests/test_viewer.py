"""The HTML viewer: a self-contained file, and points really drawn in a headless Chromium."""

from __future__ import annotations

import json
import re
import shutil
import subprocess

import numpy as np
import pytest

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.errors import MaskNetError
from masknet.viewer import MAX_POINTS_PER_LAYER, write_viewer

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="module")
def shape():
    return load_modelnet40(bundled_sample_path()).points[0]


def test_file_is_self_contained(tmp_path, shape):
    page = write_viewer(tmp_path / "v.html", {"template": shape, "source": shape[:10]}).read_text()
    assert "http://" not in page and "https://" not in page  # no CDN: works offline
    data = json.loads(re.search(r"const layers = (\[.*?\]);\n", page).group(1))
    assert [layer["name"] for layer in data] == ["template", "source"]
    assert len(data[0]["xyz"]) == 3 * len(shape)
    np.testing.assert_allclose(np.reshape(data[1]["xyz"], (-1, 3)), shape[:10], atol=1e-5)


def test_large_layers_are_subsampled_and_nan_rows_dropped(tmp_path):
    cloud = np.random.default_rng(0).normal(size=(MAX_POINTS_PER_LAYER * 2, 3))
    cloud[5] = np.nan
    page = write_viewer(tmp_path / "v.html", {"big": cloud}).read_text()
    data = json.loads(re.search(r"const layers = (\[.*?\]);\n", page).group(1))
    assert len(data[0]["xyz"]) == 3 * MAX_POINTS_PER_LAYER
    assert all(np.isfinite(data[0]["xyz"]))


def test_no_layers_is_an_error(tmp_path):
    with pytest.raises(MaskNetError):
        write_viewer(tmp_path / "v.html", {})


def _screenshot(html, png) -> np.ndarray:
    import matplotlib.image

    subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", f"--screenshot={png}",
         "--window-size=640,480", html.as_uri()],
        capture_output=True, timeout=60, check=True,
    )  # fmt: skip
    return matplotlib.image.imread(png)[..., :3]


def _count(image: np.ndarray, rgb: tuple[int, int, int]) -> int:
    return int((np.abs(image * 255 - np.array(rgb)).max(-1) < 12).sum())


def test_points_are_drawn_in_a_real_browser(tmp_path, shape, skip_unless_ci):
    if CHROMIUM is None:
        skip_unless_ci("chromium not installed (make test installs it)")
    red, green = (214, 39, 40), (44, 160, 44)
    layers = {"template": (shape, "#d62728"), "inliers": (shape[:300] + 1.0, "#2ca02c")}
    shown = _screenshot(write_viewer(tmp_path / "a.html", layers), tmp_path / "a.png")
    hidden = _screenshot(
        write_viewer(tmp_path / "b.html", layers, hidden=("template",)), tmp_path / "b.png"
    )
    assert _count(shown, red) > 1000 and _count(shown, green) > 300
    # The toggle's starting state is honoured: no red points, the green ones remain
    # (the legend swatch is the only red left).
    assert _count(hidden, red) < 150 and _count(hidden, green) > 300


def test_legends_say_when_a_layer_is_subsampled(tmp_path):
    from masknet.viewer import MAX_POINTS_PER_LAYER, write_viewer

    big = np.random.default_rng(0).random((MAX_POINTS_PER_LAYER + 500, 3))
    page = write_viewer(tmp_path / "v.html", {"big": big, "small": big[:10]}).read_text()
    assert f"{MAX_POINTS_PER_LAYER:,} of {len(big):,} shown" in page
    assert '"count":"10"' in page


def test_per_point_colours_and_the_caption_reach_the_browser(tmp_path, shape, skip_unless_ci):
    if CHROMIUM is None:
        skip_unless_ci("chromium not installed (make test installs it)")
    from masknet.viz import DISTANCE_COLOURS

    near, far = DISTANCE_COLOURS[0], DISTANCE_COLOURS[-1]
    colours = np.where(np.arange(len(shape))[:, None] < len(shape) // 2, near, far)
    page = write_viewer(
        tmp_path / "c.html", {"registered": (shape, colours)}, caption="did it work: likely correct"
    )
    assert "did it work: likely correct" in page.read_text()
    image = _screenshot(page, tmp_path / "c.png")
    assert _count(image, tuple(np.round(255 * near).astype(int))) > 300
    assert _count(image, tuple(np.round(255 * far).astype(int))) > 300

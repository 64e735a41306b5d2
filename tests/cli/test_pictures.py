"""masknet register --html: the picture answers "did it work?" (masknet.cli._pictures)."""

from __future__ import annotations

import json
import re

import numpy as np

from masknet.cli import main
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.viz import DISTANCE_COLOURS, distance_colours


def _layers(page: str) -> dict[str, dict]:
    data = json.loads(re.search(r"const layers = (\[.*?\]);\n", page, re.S).group(1))
    return {layer["name"]: layer for layer in data}


def test_the_view_opens_on_the_template_and_the_registered_source(tmp_path, capsys):
    shapes = load_modelnet40(bundled_sample_path(), "test").points[:1]
    pair = make_test_pairs(shapes, 1, PairConfig(), seed=6)
    np.savetxt(tmp_path / "t.xyz", pair.template[0].numpy())
    np.save(tmp_path / "s.npy", pair.source[0].numpy())
    args = [
        "register",
        str(tmp_path / "t.xyz"),
        str(tmp_path / "s.npy"),
        "-o",
        str(tmp_path / "m.xyz"),
    ]
    assert main([*args, "--html", str(tmp_path / "view.html")]) == 0
    verdict = capsys.readouterr().out.split("did it work: ")[1].split(":")[0]
    page = (tmp_path / "view.html").read_text()
    layers = _layers(page)
    assert [n for n, layer in layers.items() if layer["visible"]] == ["template", "registered"]
    assert not layers["source as given"]["visible"] and "rgb" not in layers["source as given"]
    # The registered points carry their distance colours: on an exact result, all the
    # scale's first colour but a few at the view's edge.
    rgb = np.array(layers["registered"]["rgb"]).reshape(-1, 3)
    first = np.round(255 * DISTANCE_COLOURS[0])
    assert len(rgb) == pair.source.shape[1]
    assert (np.abs(rgb - first).max(1) <= 30).mean() > 0.9
    assert f"did it work: {verdict}" in page
    assert (tmp_path / "view.png").stat().st_size > 10_000


def test_the_distance_scale_runs_from_its_first_colour_to_its_last():
    colours = distance_colours(np.array([0.0, 0.5, 1.0, 7.0]), limit=1.0)
    np.testing.assert_allclose(colours[0], DISTANCE_COLOURS[0])
    np.testing.assert_allclose(colours[2], DISTANCE_COLOURS[-1])
    np.testing.assert_allclose(colours[3], DISTANCE_COLOURS[-1])  # beyond the limit
    np.testing.assert_allclose(colours[1], DISTANCE_COLOURS[2])  # the middle anchor

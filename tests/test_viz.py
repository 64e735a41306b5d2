"""masknet.viz: the static pictures' titles fit the figure."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from masknet import viz  # noqa: E402

# The verdict of the carton in its Kinect scene, as `masknet register --html` titles it.
VERDICT = (
    "did it work: likely correct: at the nearest fit (0.0 degrees and 0% of the radius "
    "away), 100% of the overlap fits within 0.00235 (input units; the worse of the two "
    "directions)"
)
TITLE = "default pipeline (auto): milk_cartoon_all_small_clorox.pcd -> milk.pcd"


@pytest.fixture
def title_boxes(monkeypatch):
    """The title's box and the figure's, in pixels, of each picture drawn (as saved)."""
    boxes = []

    def measured(fig, path):
        fig.tight_layout()
        renderer = fig.canvas.get_renderer()
        boxes.append((fig.get_suptitle(), fig._suptitle.get_window_extent(renderer), fig.bbox))
        viz.pyplot().close(fig)

    monkeypatch.setattr(viz, "_save", measured)
    return boxes


def _inside(box, frame) -> bool:
    return box.x0 >= frame.x0 and box.x1 <= frame.x1 and box.y1 <= frame.y1


def test_a_long_title_is_wrapped_inside_the_picture(tmp_path, title_boxes):
    rng = np.random.default_rng(0)
    cloud = rng.normal(size=(200, 3))
    viz.plot_clouds({"scene": (cloud, "#b0b0b0")}, tmp_path / "c.png", f"{TITLE}\n{VERDICT}")
    distances = np.zeros(len(cloud))
    viz.plot_registration(cloud, cloud, cloud, distances, 1.0, tmp_path / "r.png", TITLE, VERDICT)
    mask = np.zeros(len(cloud), bool)
    viz.plot_mask(cloud, cloud[:50], mask, tmp_path / "m.png", title=f"{TITLE}: {VERDICT}")
    assert len(title_boxes) == 3
    for text, box, frame in title_boxes:
        assert _inside(box, frame), (text, box, frame)
        assert "0.00235" in text and "milk.pcd" in text  # wrapped, not cut short

"""A self-contained, offline HTML viewer for point clouds (no CDN, no WebGL needed).

:func:`write_viewer` writes one HTML file holding the clouds as JSON and ~100 lines
of plain JavaScript that draw them on a 2D canvas with perspective: drag to
rotate, wheel (or +/-) to zoom, one checkbox per layer, a point-size slider.
It opens from disk in any browser, without network access.

:func:`write_views` writes that file and its static PNG twin (:mod:`masknet.viz`, the
``viz`` extra) together, both or neither, as the commands' ``--html`` does;
:func:`scene_layers` gives the layers of an object found in a scene.
"""

from __future__ import annotations

import html
import json
import os
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from masknet._atomic import write_all
from masknet.errors import MaskNetError
from masknet.io import write_text_atomic
from masknet.viz import display_index, plot_clouds, point_count_label

__all__ = [
    "Layer",
    "write_viewer",
    "write_views",
    "view_writers",
    "scene_layers",
    "LAYER_COLOURS",
    "layer_colour",
]

# Colour per usual layer name; others cycle through the palette.
LAYER_COLOURS = {
    "template": "#9a9a9a",
    "source": "#1f77b4",
    "source as given": "#1f77b4",
    "inliers": "#2ca02c",
    "registered": "#d62728",
    "kept": "#2ca02c",
    "removed": "#ff7f0e",
    "rejected": "#ff7f0e",
}
_PALETTE = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2"]
MAX_POINTS_PER_LAYER = 30_000  # keeps files small and drawing fast; subsampled evenly

# (P, 3) points and their colour: "#rrggbb", or (P, 3) RGB in [0, 1], one per point.
Layer = tuple[np.ndarray, "str | np.ndarray"]


def layer_colour(name: str, index: int) -> str:
    """The colour of layer ``index`` named ``name``: its usual colour, else the palette's."""
    return LAYER_COLOURS.get(name, _PALETTE[index % len(_PALETTE)])


def _layer_json(points: np.ndarray, colours: np.ndarray | None) -> dict:
    """The drawn rows of a layer: coordinates, and per-point RGB (0-255) where given."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    rows = display_index(points, MAX_POINTS_PER_LAYER)
    out = {"xyz": np.round(points[rows], 5).ravel().tolist()}
    if colours is not None:
        rgb = np.clip(np.round(255 * np.asarray(colours, dtype=np.float64)[rows]), 0, 255)
        out["rgb"] = rgb.astype(int).ravel().tolist()
    return out


def write_viewer(
    path: str | os.PathLike,
    layers: Mapping[str, np.ndarray | Layer],
    title: str = "masknet",
    hidden: tuple[str, ...] = (),
    caption: str = "",
) -> Path:
    """Write an interactive 3D view of named clouds to one HTML file.

    Args:
        path: the .html file to write (atomically).
        layers: name -> (P, 3) points, or (points, "#rrggbb"). Drawn in order, so
            later layers lie on top. Layers larger than 30,000 points are
            subsampled evenly for display.
        title: page title and heading.
        hidden: names of layers whose checkbox starts unticked (one click away).
        caption: a line under the heading, e.g. the verdict of a registration.

    Returns:
        The path written.
    """
    if not layers:
        raise MaskNetError("the viewer needs at least one cloud")
    data = []
    for i, (name, layer) in enumerate(layers.items()):
        points, colour = layer if isinstance(layer, tuple) else (layer, None)
        per_point = colour is not None and not isinstance(colour, str)
        drawn = _layer_json(points, colour if per_point else None)
        total = len(np.asarray(points).reshape(-1, 3))
        data.append(
            {
                "name": name,
                # per-point colours: the swatch shows the scale's two ends
                "colour": "#5ec962" if per_point else (colour or layer_colour(name, i)),
                "scale": per_point,
                **drawn,
                "count": point_count_label(len(drawn["xyz"]) // 3, total),
                "visible": name not in hidden,
            }
        )
    page = (
        _TEMPLATE.replace("__TITLE__", html.escape(title))
        .replace("__CAPTION__", html.escape(caption))
        .replace("__DATA__", json.dumps(data, separators=(",", ":")))
    )
    path = Path(path)
    write_text_atomic(path, page)
    return path


def view_writers(
    path: str | os.PathLike,
    layers: Mapping[str, np.ndarray | Layer],
    title: str,
    hidden: tuple[str, ...] = (),
    caption: str = "",
    png: Callable[[Path], object] | None = None,
) -> list[tuple[Path, Callable[[Path], object]]]:
    """Writers, (target, write(temporary path)) for :func:`masknet._atomic.write_all`, of
    the HTML viewer at ``path`` and its static PNG twin beside it (``.png``), to write
    them with other outputs all-or-nothing. Layers, ``hidden`` and ``caption`` as
    :func:`write_viewer`'s; ``png`` writes the PNG instead of a picture of the visible
    layers (a registration's before/after panels)."""
    if png is None:
        # The PNG takes each visible layer's colour as the viewer does, so the two agree.
        coloured = {
            name: layer if isinstance(layer, tuple) else (layer, layer_colour(name, i))
            for i, (name, layer) in enumerate(layers.items())
            if name not in hidden
        }
        full_title = f"{title}\n{caption}" if caption else title

        def png(p: Path) -> object:
            return plot_clouds(coloured, p, title=full_title)

    return [
        (
            Path(path),
            lambda p: write_viewer(p, layers, title=title, hidden=hidden, caption=caption),
        ),
        (Path(path).with_suffix(".png"), png),
    ]


def write_views(
    path: str | os.PathLike, layers: Mapping[str, np.ndarray | Layer], title: str = "masknet"
) -> list[Path]:
    """Write the HTML viewer at ``path`` and its PNG twin (both or neither); returns
    their paths. The PNG needs matplotlib (``pip install 'masknet[viz]'``)."""
    writers = view_writers(path, layers, title)
    write_all(writers)
    return [p for p, _ in writers]


def scene_layers(
    template: np.ndarray, moved_scene: np.ndarray, on_object: np.ndarray, reach: float = 2.0
) -> dict[str, Layer]:
    """Viewer layers for an object found in a scene: the scene (P, 3, already in the
    template frame) within ``reach`` template radii of the template (N, 3), the template,
    and the scene points on the object (``on_object``, (P,) bool), drawn in that order."""
    from masknet.geometry.clouds import centroid_radius  # here: the viewer needs no torch

    centre = template.mean(0)
    limit = reach * centroid_radius(template)
    rest = moved_scene[~on_object]
    return {
        f"scene within {reach:g} template radii": (
            rest[np.linalg.norm(rest - centre, axis=1) <= limit],
            "#b0b0b0",
        ),
        "template": (template, "#1f77b4"),
        "found on the object": (moved_scene[on_object], "#d62728"),
    }


_TEMPLATE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>__TITLE__</title>
<style>
body{margin:0;font:14px system-ui,sans-serif;background:#fff;color:#222}
#bar{position:absolute;top:8px;left:8px;background:rgba(255,255,255,.85);padding:6px 10px;
border-radius:6px;box-shadow:0 1px 4px rgba(0,0,0,.2)}
#bar label{display:block;margin:2px 0}.sw{display:inline-block;width:10px;height:10px;
border-radius:5px;margin:0 4px 0 2px}canvas{display:block}
#help{position:absolute;bottom:6px;left:8px;color:#777;font-size:12px}
#caption{max-width:34em;margin:2px 0 4px;color:#444}#caption:empty{display:none}
</style></head><body>
<div id="bar"><b>__TITLE__</b><div id="caption">__CAPTION__</div><div id="toggles"></div>
<label>point size <input id="size" type="range" min="1" max="8" value="3"></label>
<button id="reset">reset view</button></div>
<div id="help">drag: rotate &middot; wheel or +/-: zoom &middot; shift-drag: pan</div>
<canvas id="view"></canvas>
<script>
"use strict";
const layers = __DATA__;
const canvas = document.getElementById("view"), ctx = canvas.getContext("2d");
let yaw = 0.6, pitch = -0.4, zoom = 1, panX = 0, panY = 0;
// Centre and scale from all layers together, so they keep their relative pose.
let lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
for (const l of layers) for (let i = 0; i < l.xyz.length; i += 3)
  for (let a = 0; a < 3; a++) { lo[a] = Math.min(lo[a], l.xyz[i + a]); hi[a] = Math.max(hi[a], l.xyz[i + a]); }
const mid = [0, 1, 2].map(a => (lo[a] + hi[a]) / 2);
const radius = Math.max(1e-9, ...[0, 1, 2].map(a => (hi[a] - lo[a]) / 2)) * 1.2;
const toggles = document.getElementById("toggles");
layers.forEach((l, k) => {
  const label = document.createElement("label");
  label.innerHTML = `<input type="checkbox" ${l.visible ? "checked" : ""} data-k="${k}">` +
    `<span class="sw" style="background:${l.scale ? "linear-gradient(90deg,#440154,#21918c,#fde725)" : l.colour}"></span>${l.name} (${l.count})`;
  label.querySelector("input").onchange = e => { layers[k].visible = e.target.checked; draw(); };
  toggles.appendChild(label);
});
function draw() {
  const w = canvas.width = window.innerWidth, h = canvas.height = window.innerHeight;
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, w, h);
  const cy = Math.cos(yaw), sy = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
  const scale = zoom * Math.min(w, h) / 2 / radius, size = +document.getElementById("size").value;
  const pts = [];
  layers.forEach(l => { if (!l.visible) return;
    for (let i = 0; i < l.xyz.length; i += 3) {
      const colour = l.rgb ? `rgb(${l.rgb[i]},${l.rgb[i + 1]},${l.rgb[i + 2]})` : l.colour;
      const x = l.xyz[i] - mid[0], y = l.xyz[i + 1] - mid[1], z = l.xyz[i + 2] - mid[2];
      const x1 = cy * x + sy * z, z1 = -sy * x + cy * z;       // yaw about y
      const y2 = cp * y - sp * z1, z2 = sp * y + cp * z1;       // pitch about x
      const f = 3 / (3 + z2 / radius);                          // mild perspective
      pts.push([w / 2 + panX + x1 * scale * f, h / 2 + panY - y2 * scale * f, z2, colour]);
    } });
  pts.sort((a, b) => b[2] - a[2]);                               // far first
  for (const p of pts) { ctx.fillStyle = p[3]; ctx.fillRect(p[0] - size / 2, p[1] - size / 2, size, size); }
}
let drag = null;
canvas.onmousedown = e => { drag = [e.clientX, e.clientY, e.shiftKey]; };
window.onmouseup = () => { drag = null; };
window.onmousemove = e => { if (!drag) return;
  const dx = e.clientX - drag[0], dy = e.clientY - drag[1];
  if (drag[2]) { panX += dx; panY += dy; } else { yaw += dx * 0.01; pitch += dy * 0.01; }
  drag = [e.clientX, e.clientY, drag[2]]; draw(); };
canvas.onwheel = e => { e.preventDefault(); zoom *= Math.exp(-e.deltaY * 0.001); draw(); };
window.onkeydown = e => { if (e.key === "+") zoom *= 1.1; if (e.key === "-") zoom /= 1.1; draw(); };
document.getElementById("size").oninput = draw;
document.getElementById("reset").onclick = () => { yaw = 0.6; pitch = -0.4; zoom = 1; panX = panY = 0; draw(); };
window.onresize = draw;
draw();
</script></body></html>
"""

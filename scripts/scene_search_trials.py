"""The scene search on synthetic scenes: how often it finds an object, and where it stops.

    python scripts/scene_search_trials.py --trials 20 --out docs/results/scene_search.json

Each trial builds a scene of nine bundled ModelNet40 test shapes on a 3 x 3 grid, three
radii apart, each turned at random and seen by one sensor 8 radii above the grid's centre
(hidden-point removal, shape by shape, keeps what the sensor sees). The middle one is the
object. ``register(template, scene)`` runs with its defaults (the scene search, then
Mask-ICP) for two templates:

* the view: the object's points as the scene sees them, a random half of them with
  Gaussian noise of 0.005 radii (so no point is a copy of a scene point) -- a model
  captured by the same kind of sensor, as the carton is;
* the full model: all 1,024 points of the shape, of which the scene sees one side, without
  and with the sensor's position (``SceneSearch(viewpoint=...)``).

A trial finds the object's location when the translation error is under 0.2 radii, and its
pose when the rotation error is also under 5 degrees (a symmetric shape can be found in a
turned pose that fits as well, which counts as located but not posed).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from masknet import register
from masknet.cli import run_script
from masknet.data import bundled_sample_path, load_modelnet40
from masknet.data.views import hidden_point_removal
from masknet.evaluation.registration import pose_errors
from masknet.io import write_text_atomic
from masknet.registration.stages.scene import SceneSearch

SENSOR = np.array([3.0, 3.0, 8.0])  # one depth sensor above the grid's centre


def make_scene(
    shapes: np.ndarray, trial: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(scene (P, 3), the object's visible points in its own frame, truth (4, 4) scene ->
    object frame, the object's full shape (N, 3)) for one seeded trial."""
    rng = np.random.default_rng(trial)
    picks = rng.choice(len(shapes), 9, replace=False)
    parts = []
    for cell, index in enumerate(picks):
        rot = Rotation.random(random_state=rng).as_matrix()
        shift = np.array([3.0 * (cell // 3), 3.0 * (cell % 3), 0.0])
        points = shapes[index] @ rot.T + shift
        visible = hidden_point_removal(points, SENSOR)
        parts.append(points[visible])
        if cell == 4:
            truth = np.eye(4)
            truth[:3, :3], truth[:3, 3] = rot.T, -rot.T @ shift
            seen = (points[visible] - shift) @ rot  # back in the object's own frame
            obj = shapes[index]
    return np.concatenate(parts), seen, truth, obj


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trials", type=int, default=20)
    p.add_argument("--out", type=Path, default=Path("docs/results/scene_search.json"))
    args = p.parse_args()
    shapes = load_modelnet40(bundled_sample_path(), "test").points.astype(np.float64)
    rows = []
    for trial in range(args.trials):
        scene, seen, truth, full = make_scene(shapes, trial)
        rng = np.random.default_rng(1000 + trial)
        view = seen[rng.choice(len(seen), max(3, len(seen) // 2), replace=False)]
        view = view + rng.normal(0, 0.005, view.shape)
        with_sensor = SceneSearch(viewpoint=tuple(SENSOR))
        for template_kind, template, search in (
            ("view", view, None),
            ("full model", full, None),
            ("full model, sensor position given", full, with_sensor),
        ):
            tic = time.perf_counter()
            result = register(template, scene, scene=search)
            seconds = time.perf_counter() - tic
            rot, trans = pose_errors(result.transform[None], truth[None])
            row = {
                "trial": trial,
                "template": template_kind,
                "template_points": len(template),
                "visible_fraction": len(seen) / len(full),
                "rot_deg": float(rot[0]),
                "trans": float(trans[0]),
                "searched": result.scene is not None,
                "seconds": seconds,
            }
            rows.append(row)
            print(row, flush=True)
    summary = {}
    for kind in ("view", "full model", "full model, sensor position given"):
        part = [r for r in rows if r["template"] == kind]
        located = np.array([r["trans"] < 0.2 for r in part])
        posed = located & np.array([r["rot_deg"] < 5 for r in part])
        summary[kind] = {
            "trials": len(part),
            "located": float(located.mean()),
            "posed": float(posed.mean()),
            "median_seconds": float(np.median([r["seconds"] for r in part])),
        }
    print(json.dumps(summary, indent=1))
    write_text_atomic(args.out, json.dumps({"summary": summary, "rows": rows}, indent=1))


if __name__ == "__main__":
    run_script(main)

"""The carton in the cluttered Kinect scene: a ground truth established with Open3D, and
every masknet method measured against it.

    python scripts/carton_scene.py --scans ../shared/data/scans --out docs/results/carton

Ground truth: Open3D's RANSAC on FPFH features (5 mm voxels, mutual filter, 1,000,000
iterations) from 10 seeds, each refined by point-to-plane ICP at 1 cm and then 3 mm;
the refined pose with the highest fitness (model points within 3 mm of the scene) is the
ground truth. The seeds' spread around it says how well it is determined, and the
picture (``ground_truth.png``: the model moved into the scene) is for checking by eye.
Then ``register(carton, scene, ...)`` runs for each pipeline, with and without the scene
search, and then the default pipeline on ``--trials`` random rigid motions of the scene,
with the model as it is and with a random half of its points under 1 mm of noise (so that
no model point is a copy of a scene point). Rotation and translation errors against the
ground truth, and how many kept scene points lie on the carton, go to ``carton.json``;
``found.png`` shows what the default pipeline found.
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
from masknet.evaluation.registration import pose_errors
from masknet.geometry.knn import cloud_tree
from masknet.io import read_points, require_open3d, write_text_atomic
from masknet.models import TwoSidedMaskNet
from masknet.registration.stages.scene import SceneSearch
from masknet.viewer import scene_layers, write_views


def open3d_ground_truth(
    model: np.ndarray, scene: np.ndarray, seeds: int
) -> tuple[np.ndarray, list[dict]]:
    """The model -> scene pose (4, 4) and, per seed, its fitness, RMSE and distance to it."""
    o3d = require_open3d("the carton ground truth")
    reg = o3d.pipelines.registration
    voxel = 0.005

    def prepare(points: np.ndarray):
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        down = cloud.voxel_down_sample(voxel)
        for c in (cloud, down):
            c.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=4 * voxel, max_nn=30))
        feature = reg.compute_fpfh_feature(
            down, o3d.geometry.KDTreeSearchParamHybrid(radius=10 * voxel, max_nn=100)
        )
        return cloud, down, feature

    m_full, m_down, m_feat = prepare(model)
    s_full, s_down, s_feat = prepare(scene)
    runs = []
    for seed in range(seeds):
        o3d.utility.random.seed(seed)
        coarse = reg.registration_ransac_based_on_feature_matching(
            m_down,
            s_down,
            m_feat,
            s_feat,
            True,
            1.5 * voxel,
            reg.TransformationEstimationPointToPoint(False),
            3,
            [
                reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
                reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel),
            ],
            reg.RANSACConvergenceCriteria(1_000_000, 0.9999),
        )
        pose = coarse.transformation
        for distance in (0.01, 0.003):
            pose = reg.registration_icp(
                m_full, s_full, distance, pose, reg.TransformationEstimationPointToPlane()
            ).transformation
        check = reg.evaluate_registration(m_full, s_full, 0.003, pose)
        runs.append(
            {
                "seed": seed,
                "pose": np.asarray(pose),
                "fitness": check.fitness,
                "rmse": check.inlier_rmse,
            }
        )
    best = max(runs, key=lambda r: r["fitness"])
    for r in runs:
        rot, trans = pose_errors(r["pose"][None], best["pose"][None])
        r["rot_from_best_deg"], r["trans_from_best_m"] = float(rot[0]), float(trans[0])
    return best["pose"], runs


def error_row(name: str, result, truth: np.ndarray, seconds: float, on_carton: np.ndarray) -> dict:
    """Rotation and translation errors of one result against the ground truth, its time,
    and how many of the scene points it kept lie on the ground-truth carton."""
    rot, trans = pose_errors(result.transform[None], truth[None])
    row = {"pipeline": name, "rot_deg": float(rot[0]), "trans_m": float(trans[0])}
    row["seconds"] = seconds
    if result.source_mask is not None:
        row["source_kept"] = int(result.source_mask.sum())
        row["kept_on_carton"] = int((result.source_mask & on_carton).sum())
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scans", default="../shared/data/scans")
    p.add_argument("--out", default="docs/results/carton")
    p.add_argument("--seeds", type=int, default=10)
    p.add_argument("--trials", type=int, default=5, help="random motions of the scene")
    args = p.parse_args()
    folder, out = Path(args.scans), Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model = read_points(folder / "milk.pcd", drop_nonfinite=True)
    scene = read_points(folder / "milk_cartoon_all_small_clorox.pcd", drop_nonfinite=True)
    print(f"carton {len(model)} points, scene {len(scene)} finite points", flush=True)

    model_to_scene, runs = open3d_ground_truth(model, scene, args.seeds)
    truth = np.linalg.inv(model_to_scene)  # scene (source) -> carton (template)
    np.savetxt(out / "ground_truth.txt", truth, header="scene -> carton, 4x4 (source -> template)")
    for r in runs:
        print(
            f"seed {r['seed']}: fitness {r['fitness']:.3f}, rmse {1e3 * r['rmse']:.2f} mm, "
            f"{r['rot_from_best_deg']:.2f} deg / {1e3 * r['trans_from_best_m']:.1f} mm from the best",
            flush=True,
        )
    moved = model @ model_to_scene[:3, :3].T + model_to_scene[:3, 3]
    # The scene points on the carton: within 3 mm of the ground-truth carton.
    scene_truth = np.isfinite(cloud_tree(moved).query(scene, k=1, distance_upper_bound=0.003)[0])
    # The scene within 25 cm of the carton, so that the fit can be checked by eye.
    near = scene[np.linalg.norm(scene - moved.mean(0), axis=1) < 0.25]
    layers = {
        "scene (25 cm around)": (near, "#9a9a9a"),
        "carton (ground truth)": (moved, "#d62728"),
    }
    write_views(str(out / "ground_truth.html"), layers, "Carton: ground truth")

    two_sided = TwoSidedMaskNet.pretrained()
    pipelines = {
        "Mask-ICP (the default: scene search, then Mask-ICP)": {},
        "robust (scene search, then robust)": {"method": "robust"},
        "Mask-ICP, the Kinect's position given (viewpoint 0 0 0)": {
            "scene": SceneSearch(viewpoint=(0.0, 0.0, 0.0))
        },
        "ICP (scene search, then ICP)": {"use_mask": False},
        "Mask-ICP without the scene search": {"scene": False},
        "two-sided Mask-ICP without the scene search": {"scene": False, "model": two_sided},
        "robust without the scene search": {"method": "robust", "scene": False},
        "Open3D RANSAC + ICP (voxel 0.05 of the radius)": {
            "method": "open3d-ransac",
            "use_mask": False,
            "refine_iterations": 10,
            "scene": False,
        },
    }
    rows = []
    for name, kwargs in pipelines.items():
        tic = time.perf_counter()
        result = register(model, scene, **kwargs)
        rows.append(error_row(name, result, truth, time.perf_counter() - tic, scene_truth))
        print(rows[-1], flush=True)
        if name.startswith("Mask-ICP (the default"):
            moved_scene = scene @ result.R.T + result.t
            layers = scene_layers(model, moved_scene, result.source_mask)
            write_views(str(out / "found.html"), layers, "The carton found in the scene")

    # Harder variants: the scene moved, and a resampled, noisy model (no point in common).
    rng = np.random.default_rng(0)
    trials = []
    for seed in range(args.trials):
        motion = np.eye(4)
        motion[:3, :3] = Rotation.random(random_state=seed).as_matrix()
        motion[:3, 3] = rng.uniform(-1, 1, 3)
        moved_scene = scene @ motion[:3, :3].T + motion[:3, 3]
        half = model[rng.choice(len(model), len(model) // 2, replace=False)]
        noisy = half + rng.normal(0, 0.001, half.shape)
        for variant, template in (("model", model), ("half the model, 1 mm noise", noisy)):
            tic = time.perf_counter()
            result = register(template, moved_scene)
            row = error_row(
                f"scene moved (seed {seed}), {variant}",
                result,
                truth @ np.linalg.inv(motion),
                time.perf_counter() - tic,
                scene_truth,
            )
            trials.append(row)
            print(row, flush=True)
    report = {
        "ground_truth": truth.tolist(),
        "seeds": [{k: v for k, v in r.items() if k != "pose"} for r in runs],
        "pipelines": rows,
        "trials": trials,
    }
    write_text_atomic(out / "carton.json", json.dumps(report, indent=1))


if __name__ == "__main__":
    run_script(main)

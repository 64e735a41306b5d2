"""Time against the number of points: the default and Open3D's tutorial pipeline.

    python scripts/scaling.py [--out docs/results/scaling] [--voxel 0.05]

One real scan, the cluttered Kinect scene of the evaluation scans (241,407 finite points,
about 2 m across), made into a pair with a known answer: the template is the scan, the
source the 80% of it on one side of a plane, turned 20 degrees and shifted 20 cm. Both are
randomly subsampled to each size from 512 points to the whole scan, and for 1 and 2
million points densified (each point joined by jittered copies, a quarter of the scan's
spacing away). For each size, one call of ``register`` and one of Open3D's tutorial
pipeline (RANSAC on FPFH at ``--voxel`` metres, then point-to-plane ICP on the full
clouds), timed in one process, with their errors. Writes a Markdown table, JSON and a
log-log plot.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np

from masknet.cli import run_script

SIZES = (512, 2048, 8192, 32768, 131072, 241407, 1_000_000, 2_000_000)
TURN_DEG, SHIFT_M = 20.0, 0.2


def make_pair(scene: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Template (the scene), source (80% of it, moved), and the true source -> template."""
    from scipy.spatial.transform import Rotation

    along = scene @ np.array([0.6, 0.0, 0.8])
    view = scene[along <= np.quantile(along, 0.8)]
    rotation = Rotation.from_rotvec(np.radians(TURN_DEG) * np.array([0.0, 1.0, 0.0])).as_matrix()
    shift = np.array([SHIFT_M, 0.0, 0.0])
    source = view @ rotation.T + shift  # moved away; the truth moves it back
    truth = np.eye(4)
    truth[:3, :3], truth[:3, 3] = rotation.T, -rotation.T @ shift
    return scene, source, truth


def resize(points: np.ndarray, count: int, spacing: float, rng: np.random.Generator) -> np.ndarray:
    """``count`` points: a random subset, or the cloud with jittered copies added."""
    if count <= len(points):
        return points[rng.choice(len(points), count, replace=False)]
    copies = -(-count // len(points))
    jitter = rng.normal(scale=spacing / 4, size=(copies - 1, len(points), 3))
    dense = np.concatenate([points[None], points[None] + jitter]).reshape(-1, 3)
    return dense[rng.choice(len(dense), count, replace=False)]


def main() -> None:
    from masknet import register
    from masknet.evaluation.registration import pose_errors
    from masknet.experiments.real_pairs import open3d_tutorial
    from masknet.experiments.scans import scans_folder
    from masknet.geometry.clouds import median_spacing
    from masknet.io import read_points

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/results/scaling"))
    parser.add_argument("--voxel", type=float, default=0.05, help="the tutorial's voxel, m")
    parser.add_argument("--sizes", default=",".join(map(str, SIZES)))
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    scene = read_points(scans_folder() / "milk_cartoon_all_small_clorox.pcd", drop_nonfinite=True)
    template_all, source_all, truth = make_pair(scene)
    spacing = median_spacing(scene, sample=4096)
    register(template_all[:4096], source_all[:4096])  # warm start: models, imports
    rows = []
    for size in map(int, args.sizes.split(",")):
        rng = np.random.default_rng(size)
        template = resize(template_all, size, spacing, rng)
        source = resize(source_all, int(0.8 * size), spacing, rng)
        tic = time.perf_counter()
        result = register(template, source)
        seconds = time.perf_counter() - tic
        rot, shift = (float(e[0]) for e in pose_errors(result.transform[None], truth[None]))
        tic = time.perf_counter()
        peer = open3d_tutorial(template, source, args.voxel)
        peer_seconds = time.perf_counter() - tic
        peer_rot, peer_shift = (float(e[0]) for e in pose_errors(peer[None], truth[None]))
        rows.append(
            {
                "template_points": len(template),
                "source_points": len(source),
                "seconds": seconds,
                "rot_deg": rot,
                "trans_m": shift,
                "path": str(result.info["path"]),
                "tutorial_seconds": peer_seconds,
                "tutorial_rot_deg": peer_rot,
                "tutorial_trans_m": peer_shift,
            }
        )
        print(json.dumps(rows[-1]), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "scaling.json").write_text(json.dumps(rows, indent=1) + "\n")
    _table(rows, args.voxel)
    _plot(rows, args.out / "scaling.png", args.voxel)


def _table(rows: list[dict], voxel: float) -> None:
    print(
        f"\n| template points | default s | default error | path | tutorial ({voxel * 100:g} cm) s "
        "| tutorial error |"
    )
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['template_points']:,} | {r['seconds']:.2f} | {r['rot_deg']:.2f}°, "
            f"{100 * r['trans_m']:.1f} cm | {r['path']} | {r['tutorial_seconds']:.2f} "
            f"| {r['tutorial_rot_deg']:.2f}°, {100 * r['tutorial_trans_m']:.1f} cm |"
        )


def _plot(rows: list[dict], path: Path, voxel: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = [r["template_points"] for r in rows]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.loglog(points, [r["seconds"] for r in rows], "o-", label="register (default)")
    ax.loglog(
        points,
        [r["tutorial_seconds"] for r in rows],
        "s--",
        label=f"Open3D tutorial ({voxel * 100:g} cm voxel)",
    )
    ax.set_xlabel("template points (source: 0.8 times as many)")
    ax.set_ylabel("seconds per call")
    ax.set_title("Time against size: a Kinect scene, subsampled or densified")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    run_script(main)

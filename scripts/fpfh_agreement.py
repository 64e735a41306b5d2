"""CrossMaskNet's FPFH descriptors by numpy against Open3D's, cloud by cloud.

    python scripts/fpfh_agreement.py --data .../modelnet40_1024_int16.npz [--clouds 30]
        [--scans .../scans]

``masknet.models.descriptors.numpy_fpfh_descriptors`` against the Open3D path it replaced
(``masknet.geometry.features.fpfh_features`` with ``orient=True``, divided by 200, at the
same scale): the first ``--clouds`` ModelNet40 test clouds, the same clouds each turned by
a random rotation (up to 180 degrees), and the real scans of ``--scans`` (2,048-point subsamples and whole).
Prints the largest and mean absolute difference of the (P, 33) descriptors and how many
points differ by more than 1e-4. Needs Open3D.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from masknet.cli import run_script

SCANS = ("o3d_feature_cloud_bin_0.pcd", "o3d_feature_cloud_bin_1.pcd", "milk.pcd")


def main() -> None:
    import open3d as o3d
    import torch

    from masknet.data import load_modelnet40
    from masknet.geometry import random_rotation

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True, help="ModelNet40 .npz")
    parser.add_argument("--clouds", type=int, default=30, help="test clouds compared")
    parser.add_argument("--scans", help="folder of the real scans (data/scans)")
    args = parser.parse_args()
    points = load_modelnet40(args.data, "test").points[: args.clouds]
    clouds = [np.asarray(p, np.float32) for p in points]
    _report("ModelNet40 test", clouds)
    turns = random_rotation(len(clouds), 180.0, torch.Generator().manual_seed(0)).numpy()
    _report("the same, turned", [c @ t.T for c, t in zip(clouds, turns, strict=True)])
    if args.scans:
        scans = []
        for name in (*SCANS, "bun_zipper_res3.ply"):
            cloud = np.asarray(o3d.io.read_point_cloud(str(Path(args.scans) / name)).points)
            cloud = cloud[np.isfinite(cloud).all(1)]
            pick = np.random.default_rng(0).choice(len(cloud), min(len(cloud), 2048), False)
            scans += [cloud[pick], cloud]
        _report("scans", scans)
        demo = Path(args.scans) / "geotransformer_demo_src.npy"
        _report("3DMatch fragment (voxel grid)", [np.load(demo)])


def _open3d(cloud: np.ndarray) -> np.ndarray:
    """The descriptors as Open3D computed them before (P, 33) float32."""
    import open3d as o3d

    from masknet.geometry.clouds import median_spacing
    from masknet.geometry.features import fpfh_features
    from masknet.models.descriptors import FPFH_NEIGHBOURS, FPFH_SPACINGS

    cloud = np.ascontiguousarray(cloud, np.float64)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud))
    voxel = FPFH_SPACINGS * median_spacing(cloud)
    feature = fpfh_features(o3d, pc, voxel, FPFH_NEIGHBOURS, orient=True)
    return (np.asarray(feature.data).T / 200.0).astype(np.float32)


def _report(name: str, clouds: list) -> None:
    from masknet.models.descriptors import numpy_fpfh_descriptors

    worst, total, count, off = 0.0, 0.0, 0, 0
    for cloud in clouds:
        gap = np.abs(_open3d(cloud) - numpy_fpfh_descriptors(cloud))
        worst = max(worst, float(gap.max()))
        total, count = total + float(gap.sum()), count + gap.size
        off += int((gap.max(1) > 1e-4).sum())
    points = sum(len(c) for c in clouds)
    print(
        f"{name}: {len(clouds)} clouds, {points} points: max |diff| {worst:.3g}, "
        f"mean {total / count:.3g}, points off by > 1e-4: {off}",
        flush=True,
    )


if __name__ == "__main__":
    run_script(main)

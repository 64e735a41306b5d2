"""``scans``: zero-shot registration of real scans with the ModelNet40-trained networks."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from masknet.errors import MaskNetError
from masknet.evaluation.registration import pose_errors
from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.experiments.pipelines import SWEEP_PIPELINES
from masknet.geometry.se3 import so3_exp
from masknet.registration.api import register

# The 3DMatch fragment pair of ../shared/data/scans: template, source, ground truth.
THREEDMATCH_FILES = (
    "geotransformer_demo_ref.npy",
    "geotransformer_demo_src.npy",
    "geotransformer_demo_gt.npy",
)
# (name, template file, source file, ground truth file or None) in ../shared/data/scans.
SCAN_PAIRS = [
    ("3DMatch pair (GeoTransformer demo)", *THREEDMATCH_FILES),
    (
        "3DMatch pair (Open3D, downsampled)",
        "o3d_feature_cloud_bin_0.pcd",
        "o3d_feature_cloud_bin_1.pcd",
        None,
    ),
    ("two room scans", "room_scan1.pcd", "room_scan2.pcd", None),
    (
        "carton model in a cluttered Kinect scene",
        "milk.pcd",
        "milk_cartoon_all_small_clorox.pcd",
        None,
    ),
    ("RGB-D fragment vs the first room scan", "fragment.pcd", "room_scan1.pcd", None),
    (
        "bunny vs its own first 60% (x-sorted), moved",
        "bun_zipper_res3.ply",
        "bun_zipper_res3.ply",
        "partial",
    ),
]

PIPELINES = SWEEP_PIPELINES | {
    "Mask-ICP + 30 ICP refine": {"method": "icp", "use_mask": True, "refine_iterations": 30},
    "default (auto)": {},
    "robust": {"method": "robust"},
}


def scans_folder() -> Path:
    """``$MASKNET_SCANS``, else ../shared/data/scans beside the working directory."""
    return Path(os.environ.get("MASKNET_SCANS", "../shared/data/scans"))


def load_pair(
    folder: Path, template_file: str, source_file: str, truth_file: str | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Template (N, 3), source (M, 3) and the true (4, 4) transform (or None)."""
    from masknet.io import read_points

    template = read_points(folder / template_file, drop_nonfinite=True)
    source = read_points(folder / source_file, drop_nonfinite=True)
    truth = None
    if truth_file == "partial":  # a synthetic check on a real scan: known motion
        part = source[np.argsort(source[:, 0])[: int(0.6 * len(source))]]
        rot = so3_exp(torch.tensor([0.3, -0.2, 0.4], dtype=torch.float64)).numpy()
        shift = np.array([0.02, -0.01, 0.03])
        source = part @ rot.T + shift
        truth = np.eye(4)
        truth[:3, :3], truth[:3, 3] = rot.T, -rot.T @ shift
    elif truth_file is not None:
        truth = np.load(folder / truth_file)
    return template, source, truth


def run(ctx: BenchmarkContext) -> ExperimentResult:
    """Zero-shot registration of real scans with the ModelNet40-trained networks."""
    folder = scans_folder()
    if not folder.is_dir():
        raise MaskNetError(
            f"{folder}: scan folder not found; set MASKNET_SCANS to the folder holding the "
            "3DMatch, room, carton and bunny scans (see ../shared/data/README.md)"
        )
    rows = []
    pairs = SCAN_PAIRS[:1] + SCAN_PAIRS[-1:] if ctx.quick else SCAN_PAIRS
    for title, *files in pairs:
        template, source, truth = load_pair(folder, *files)
        for name, kwargs in PIPELINES.items():
            result = register(template, source, **kwargs)
            row = {
                "pair": title,
                "pipeline": name,
                "points": f"{len(template)} / {len(source)}",
                "sampled": f"{result.sampled[0]} / {result.sampled[1]}",
                "ms": 1e3 * result.times["total"],
                "rotation_deg": float(result.rotation_deg),
                "rot_error_deg": np.nan,
                "trans_error": np.nan,
            }
            if truth is not None:
                rot_err, trans_err = pose_errors(result.transform[None], truth[None])
                row["rot_error_deg"], row["trans_error"] = float(rot_err[0]), float(trans_err[0])
            rows.append(row)
    summary = (
        "template / source points as read (non-finite rows dropped), sampled to the network's "
        "1,024 by farthest point sampling; errors only where a ground truth exists (units of "
        "the scan: metres for 3DMatch, the bunny's own units)."
    )
    return ExperimentResult(rows, summary)

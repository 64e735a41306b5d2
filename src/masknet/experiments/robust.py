"""``robust``: ``method="robust"`` against Open3D's global pipelines, each peer tuned.

Sets (seeded, the same pairs for every pipeline): the paper's protocol clean, with
Gaussian noise of sigma 0.01 and 0.02, with 10% uniform source outliers, with rotations
up to 180 degrees; *resampled* ModelNet40 pairs (template and source drawn from disjoint
halves of each shape, so no point is copied); and pairs cut from the evaluation scans.

Peers, with the voxel size (FPFH feature scale, as a fraction of the template's radius)
swept as a user would tune it: Open3D RANSAC on FPFH + 10 ICP iterations, FGR on FPFH
+ 10 ICP iterations; and Open3D's ICP. The summary names each peer's best voxel per set.
Every call is a single pair (batch 1), timed end to end.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from masknet.data.pairs import PairConfig, Pairs
from masknet.evaluation.registration import pair_arrays, pose_errors, summarize_errors
from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.registration.api import register

VOXELS = (0.02, 0.035, 0.05, 0.075, 0.1)
PEERS = ("Open3D RANSAC + ICP", "Open3D FGR + ICP")


def pipelines(voxels: tuple[float, ...]) -> dict[str, dict]:
    """Pipeline name -> register() arguments."""
    out = {
        "robust (two-sided Mask-ICP, 24 hypotheses)": {"method": "robust"},
        "Mask-ICP x3 + 10 ICP": {"method": "icp", "iterations": 3, "refine_iterations": 10},
        "Open3D ICP": {"method": "open3d-icp", "use_mask": False},
    }
    for v in voxels:
        for peer, method in zip(PEERS, ("open3d-ransac", "open3d-fgr"), strict=True):
            out[f"{peer} (voxel {v})"] = {
                "method": method,
                "use_mask": False,
                "voxel_size": v,
                "refine_iterations": 10,
            }
            if method == "open3d-ransac":  # its fastest setting: all threads
                out[f"{peer} (voxel {v})"]["repeatable"] = False
    return out


def timed_errors(pairs: Pairs, **kwargs: object) -> dict[str, float]:
    """Errors (mean, median, 90th percentile, RMSE) and the median ms of single-pair
    register calls over every pair."""
    template, source, truth = pair_arrays(pairs)
    estimates, seconds = np.empty_like(truth), []
    for i in range(len(truth)):
        tic = time.perf_counter()
        estimates[i] = register(template[i], source[i], **kwargs).transform
        seconds.append(time.perf_counter() - tic)
    rot, trans = pose_errors(estimates, truth)
    return summarize_errors(rot, trans) | {
        "rot_p90": float(np.percentile(rot, 90)),
        "ms_median": 1e3 * float(np.median(seconds)),
    }


def _resampled(ctx: BenchmarkContext, count: int) -> Pairs:
    from masknet.data.views import ViewConfig, make_view_pairs, normalize_cloud

    rng = np.random.default_rng(ctx.seed)
    picks = rng.choice(len(ctx.points), count, replace=False)
    view = ViewConfig(template_points=512, noise_sigma=0.0, falloff=0.0)
    return make_view_pairs([normalize_cloud(ctx.points[i]) for i in picks], view, rng)


def _scan_pairs(ctx: BenchmarkContext, count: int) -> Pairs | None:
    from masknet.data.scans import load_scans, make_scan_test_pairs
    from masknet.data.views import ViewConfig
    from masknet.errors import MaskNetError
    from masknet.experiments.scans import scans_folder

    try:
        scans = load_scans(scans_folder(), quiet=True)
    except MaskNetError:
        return None
    per_scan = max(1, count // len(scans))
    return make_scan_test_pairs(scans, per_scan, ViewConfig(), seed=ctx.seed)[0]


def run(ctx: BenchmarkContext) -> ExperimentResult:
    """Every pipeline on every set; the best voxel of each peer per set in the summary."""
    count = ctx.pairs if not ctx.quick else min(ctx.pairs, 4)
    voxels = VOXELS if not ctx.quick else (0.05,)
    sets: dict[str, Pairs | None] = {
        "clean": ctx.test_pairs(PairConfig(), count),
        "noise 0.01": ctx.test_pairs(PairConfig(noise_sigma=0.01), count),
        "noise 0.02": ctx.test_pairs(PairConfig(noise_sigma=0.02), count),
        "outliers 10%": ctx.test_pairs(PairConfig(outlier_ratio=0.1), count),
        "resampled": _resampled(ctx, count),
        "rotation <= 180": ctx.test_pairs(PairConfig(max_angle_deg=180.0), count),
        "scans": None if ctx.quick else _scan_pairs(ctx, count),
    }
    rows = []
    for set_name, pairs in sets.items():
        if pairs is None:
            continue
        for name, kwargs in pipelines(voxels).items():
            rows.append(ctx.row({"set": set_name, "pipeline": name}, timed_errors, pairs, **kwargs))

    lines = []
    for set_name in dict.fromkeys(r["set"] for r in rows):
        mine = [r for r in rows if r["set"] == set_name]
        robust = next(r for r in mine if r["pipeline"].startswith("robust"))
        for peer in PEERS:
            tuned = [r for r in mine if r["pipeline"].startswith(peer)]
            best = min(tuned, key=lambda r: r["rot_mean"])
            lines.append(
                f"| {set_name} | {peer} | {best['pipeline'].split('voxel ')[1].rstrip(')')} | "
                f"{best['rot_mean']:.3g} | {best['ms_median']:.3g} | {robust['rot_mean']:.3g} | "
                f"{robust['ms_median']:.3g} | {robust['ms_median'] / best['ms_median']:.2f} |"
            )
    summary = (
        f"{count} pairs per set (scans: an equal share per evaluation scan), single-pair calls; "
        "rotation errors in degrees, times in ms (median). Each peer's voxel size was swept over "
        f"{', '.join(str(v) for v in voxels)} of the template radius; its best setting per set "
        "(lowest mean rotation error) against robust:\n\n"
        "| set | peer | best voxel | peer mean | peer ms | robust mean | robust ms | "
        "time ratio |\n|---|---|---|---|---|---|---|---|\n" + "\n".join(lines)
    )

    def plot(path: Path) -> None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        names = list(dict.fromkeys(r["set"] for r in rows))
        fig, ax = plt.subplots(figsize=(9, 4))
        shown = ["robust", "Mask-ICP x3", *PEERS]
        width = 0.8 / len(shown)
        for j, prefix in enumerate(shown):
            means = []
            for set_name in names:
                cand = [
                    r for r in rows if r["set"] == set_name and r["pipeline"].startswith(prefix)
                ]
                means.append(min(r["rot_mean"] for r in cand))
            label = prefix + (" (best voxel)" if prefix in PEERS else "")
            ax.bar(np.arange(len(names)) + j * width, means, width, label=label)
        ax.set_xticks(np.arange(len(names)) + 0.4 - width / 2, names)
        ax.set_ylabel("mean rotation error (degrees)")
        ax.set_yscale("symlog", linthresh=0.1)
        ax.legend(fontsize=8)
        ax.set_title("Robust registration against tuned global pipelines")
        fig.tight_layout()
        fig.savefig(path, dpi=120)
        plt.close(fig)

    return ExperimentResult(rows, summary, plot)

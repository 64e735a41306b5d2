"""``masknet benchmark EXPERIMENT``: the paper's experiments, seeded, one command each.

Every experiment builds its pairs from the ModelNet40 test split with a seed,
runs the methods on the same pairs, and writes ``<out>/<experiment>.json``,
``.csv`` and ``.png``. With ``results=`` it also rewrites the experiment's block
in docs/RESULTS.md (between ``<!-- benchmark:NAME -->`` markers), so the
document always shows what the last run measured and the command that did it.

Every table row is also appended to ``<out>/.rows/<experiment>.jsonl`` as soon as it
is computed. ``--resume`` (``BenchmarkContext(resume=True)``) reads those rows back
instead of recomputing them, when their settings, the package version, the shipped
weights and the test shapes all match, so a full-size run killed after hours loses
at most the row in progress.

Registration methods run with the paper's budget (10 iterations) and the shipped
weights. Errors: rotation in degrees (angle of R_est^T R_true), translation as
||t_est - t_true|| in units of the unit-radius shapes.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from masknet.data.modelnet import PointCloudSet, load_modelnet40
from masknet.data.pairs import PairConfig, Pairs, make_test_pairs
from masknet.errors import MaskNetError
from masknet.evaluation.evaluate import PAIRS_PER_CALL, evaluate_masknet
from masknet.evaluation.metrics import outlier_removal_metrics
from masknet.evaluation.registration import (
    PIPELINES,
    benchmark_registration,
    iteration_errors,
    pose_errors,
    summarize_errors,
)
from masknet.geometry.se3 import invert_transform, make_transform, so3_exp
from masknet.io import write_text_atomic
from masknet.models.masknet import MIN_POINTS, MaskNet
from masknet.models.weights import shipped_weights_path
from masknet.registration.api import register
from masknet.runtime import default_precision

__all__ = ["EXPERIMENTS", "BenchmarkContext", "run_benchmark"]

# X and Mask-X for each method that has shipped weights (the sweeps' lines).
SWEEP_PIPELINES = {
    "ICP": {"method": "icp", "use_mask": False},
    "Mask-ICP": {"method": "icp", "use_mask": True},
    "PointNetLK": {"method": "pointnetlk", "use_mask": False},
    "Mask-PointNetLK": {"method": "pointnetlk", "use_mask": True},
}
# The learned back-ends beyond PointNetLK, by display name (method names of register()).
LEARNED = {"DCP": "dcp", "PRNet": "prnet", "PCRNet": "pcrnet", "RPM-Net": "rpmnet"}


def sweep_pipelines() -> dict[str, dict]:
    """X and Mask-X for ICP, PointNetLK and every learned back-end whose weights ship."""
    pipelines = dict(SWEEP_PIPELINES)
    for name, method in LEARNED.items():
        if _shipped(method):
            pipelines[name] = {"method": method, "use_mask": False}
            pipelines[f"Mask-{name}"] = {"method": method, "use_mask": True}
    return pipelines


# The paper's Table (GTX 1070), ms per pair: X, Mask-X.
PAPER_TIMING_MS = {
    "ICP": (6.82, 9.83),
    "PointNetLK": (52.30, 58.15),
    "DCP": (23.99, 24.68),
    "PRNet": (68.52, 82.18),
}


@dataclass
class BenchmarkContext:
    """What every experiment gets: test shapes (loaded on first use), seed, size, output."""

    data: str | os.PathLike | None = None  # ModelNet40 path; None: $MASKNET_DATA
    pairs: int = 1000
    seed: int = 0
    quick: bool = False
    out: Path = Path("masknet_benchmark")
    progress: bool = True
    command: str = ""
    resume: bool = False  # keep the rows an interrupted invocation already computed
    experiment: str = ""  # set by run_benchmark: the experiment whose rows row() records
    reused: dict[str, float] = field(default_factory=lambda: {"rows": 0, "seconds": 0.0})
    # called with one line per table row computed or kept: a log's only sign of life in a
    # long experiment when stderr is not a terminal (no progress bars)
    log: Callable[[str], None] | None = None
    _test: PointCloudSet | None = None
    _fingerprint: str | None = None
    _kept: dict[str, dict] | None = None

    @property
    def test_set(self) -> PointCloudSet:
        if self._test is None:
            self._test = load_modelnet40(self.data, "test")
        return self._test

    @property
    def points(self) -> np.ndarray:
        """(S, N, 3) ModelNet40 test shapes."""
        return self.test_set.points

    @property
    def categories(self) -> np.ndarray:
        """(S,) category index of each test shape."""
        return self.test_set.labels

    def test_pairs(self, config: PairConfig | None = None, count: int | None = None) -> Pairs:
        return make_test_pairs(self.points, count or self.pairs, config or PairConfig(), self.seed)

    @property
    def fingerprint(self) -> str:
        """A digest of what a row depends on beyond its key: the package version, every
        shipped weight file and the test shapes."""
        if self._fingerprint is None:
            from masknet import __version__

            digest = hashlib.sha256(__version__.encode())
            for path in sorted(shipped_weights_path("").glob("*.safetensors")):
                digest.update(path.name.encode() + path.read_bytes())
            digest.update(np.ascontiguousarray(self.points).tobytes())
            self._fingerprint = digest.hexdigest()[:16]
        return self._fingerprint

    @property
    def rows_file(self) -> Path:
        """``<out>/.rows/<experiment>.jsonl``: every row computed, one JSON line each."""
        return self.out / ".rows" / f"{self.experiment}.jsonl"

    def start_experiment(self, name: str) -> None:
        """Point :meth:`row` at ``name``; without ``resume``, forget its earlier rows."""
        self.experiment, self._kept = name, None
        self.reused = {"rows": 0, "seconds": 0.0}
        if not self.resume:
            self.rows_file.unlink(missing_ok=True)

    def row(self, key: dict, compute: Callable[..., dict], *args: object, **kwargs: object) -> dict:
        """One table row, ``{**key, **compute(*args, **kwargs)}``.

        The row is appended to :attr:`rows_file` as soon as it is computed. With
        ``resume``, a row recorded there for the same key, pairs, seed, quick flag and
        :attr:`fingerprint` is read back instead of computed, so a killed run, restarted
        with ``--resume``, loses at most the row it was computing.
        """
        ident = json.dumps(
            {**key, "pairs": self.pairs, "seed": self.seed, "quick": self.quick},
            sort_keys=True,
            default=str,
        )
        ident += f" {self.fingerprint}"
        if self.resume:
            if self._kept is None:
                self._kept = _read_rows(self.rows_file)
            kept = self._kept.get(ident)
            if kept is not None:
                self.reused["rows"] += 1
                self.reused["seconds"] += kept["seconds"]
                self._log_row(key, "kept from an earlier invocation")
                return kept["row"]
        tic = time.perf_counter()
        row = {**key, **compute(*args, **kwargs)}
        entry = {"id": ident, "seconds": time.perf_counter() - tic, "row": row}
        self.rows_file.parent.mkdir(parents=True, exist_ok=True)
        with open(self.rows_file, "a") as f:
            f.write(json.dumps(entry) + "\n")
        self._log_row(key, f"{entry['seconds']:.0f} s")
        return row

    def _log_row(self, key: dict, how: str) -> None:
        if self.log is not None:
            what = ", ".join(f"{k} {v}" for k, v in key.items())
            self.log(f"{self.experiment}: {what}: {how}")


def _read_rows(path: Path) -> dict[str, dict]:
    """id -> entry of a rows file. A line torn by a kill mid-write is ignored, and cut
    off the file, so that the next row appended starts a line of its own."""
    kept = {}
    if path.exists():
        text = path.read_text()
        if text and not text.endswith("\n"):
            text = text[: text.rfind("\n") + 1]
            write_text_atomic(path, text)
        for line in text.splitlines():
            try:
                entry = json.loads(line)
                kept[entry["id"]] = entry
            except (json.JSONDecodeError, KeyError, TypeError):
                continue
    return kept


@dataclass
class ExperimentResult:
    """A table (list of rows with the same keys), a plot, and a few lines of context."""

    rows: list[dict]
    summary: str
    plot: Callable[[Path], None] | None = None


def _batched_errors(
    pairs: Pairs, chunk: int = PAIRS_PER_CALL, **kwargs: object
) -> dict[str, float]:
    """Errors of one pipeline over every pair, in batched register calls of ``chunk`` pairs."""
    template, source = pairs.template.double().numpy(), pairs.source.double().numpy()
    estimates = [
        register(template[i : i + chunk], source[i : i + chunk], **kwargs).transform
        for i in range(0, len(template), chunk)
    ]
    truth = pairs.transform.double().numpy()
    return summarize_errors(*pose_errors(np.concatenate(estimates), truth))


def _line_plot(
    path: Path,
    x: list[float],
    lines: dict[str, list[float]],
    xlabel: str,
    ylabel: str,
    title: str,
    baseline: tuple[str, list[float]] | None = None,
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4 if len(lines) <= 6 else 7.6, 4.2), dpi=110)
    # One colour per method X, Mask-X solid and plain X dashed.
    bases = list(dict.fromkeys(name.removeprefix("Mask-") for name in lines))
    palette = plt.get_cmap("tab10")
    for name, ys in lines.items():
        style = "-" if "Mask" in name else "--"
        colour = palette(bases.index(name.removeprefix("Mask-")) % 10)
        ax.plot(x, ys, style, marker="o", markersize=4, color=colour, label=name)
    if baseline is not None:
        ax.plot(x, baseline[1], ":", color="grey", label=baseline[0])
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small", ncol=2 if len(lines) > 6 else 1)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _bar_plot(
    path: Path, names: list[str], series: dict[str, list[float]], ylabel: str, title: str
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.2), dpi=110)
    width = 0.8 / len(series)
    for i, (label, values) in enumerate(series.items()):
        ax.bar(np.arange(len(names)) + i * width, values, width, label=label)
    ax.set_xticks(np.arange(len(names)) + width * (len(series) - 1) / 2)
    ax.set_xticklabels(names, rotation=20, ha="right")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(axis="y", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _error_bars(path: Path, rows: list[dict], title: str) -> None:
    """Mean and median rotation error of each pipeline row, as bars."""
    _bar_plot(
        path,
        [r["pipeline"] for r in rows],
        {"mean": [r["rot_mean"] for r in rows], "median": [r["rot_median"] for r in rows]},
        "rotation error (degrees)",
        title,
    )


# ------------------------------------------------------------------------- experiments


def _registration_row(pairs: Pairs, name: str, kwargs: dict, progress: bool) -> dict:
    return benchmark_registration(pairs, {name: kwargs}, progress=progress)[name]


def _network_row(pairs: Pairs, timing_pairs: Pairs, repeats: int, kwargs: dict) -> dict:
    """Errors over ``pairs`` (batched) and batch-1 times over ``timing_pairs``."""
    return _batched_errors(pairs, **kwargs) | time_pipeline(
        timing_pairs, repeats, warmup=2, **kwargs
    )


def _rounds_row(pairs: Pairs, method: str, progress: bool) -> dict:
    return {"rounds": iteration_errors(pairs, 3, progress=progress, method=method)}


def exp_registration(ctx: BenchmarkContext) -> ExperimentResult:
    """X against Mask-X (and refinements) on the default protocol, pair by pair."""
    pairs = ctx.test_pairs()
    rows = [
        ctx.row({"pipeline": name}, _registration_row, pairs, name, kwargs, ctx.progress)
        for name, kwargs in PIPELINES.items()
    ]
    best = min(rows, key=lambda r: r["rot_median"])

    def plot(path: Path) -> None:
        _error_bars(
            path,
            rows,
            f"Registration on {len(pairs.template)} ModelNet40 test pairs (30% missing, <=45 deg)",
        )

    summary = (
        f"{len(pairs.template)} pairs, 30% missing, rotation <= 45 deg, translation in [-1, 1]^3; "
        f"lowest median rotation error: {best['pipeline']} ({best['rot_median']:.2f} deg)."
    )
    return ExperimentResult(rows, summary, plot)


def _shipped(method: str) -> bool:
    """Whether the package ships weights for a learned registration method."""
    from masknet.models import REGISTRATION_NETWORKS
    from masknet.models.weights import shipped_weights_path

    prefix = REGISTRATION_NETWORKS[method].weights_prefix
    return shipped_weights_path(f"{prefix}modelnet40.safetensors").exists()


def exp_networks(ctx: BenchmarkContext) -> ExperimentResult:
    """The learned back-ends (DCP, PRNet, PCRNet, RPM-Net): X against Mask-X, and no motion."""
    pairs = ctx.test_pairs()
    truth = pairs.transform.double().numpy()
    identity = np.broadcast_to(np.eye(4), truth.shape)
    rows = [{"pipeline": "Identity (no motion)", **summarize_errors(*pose_errors(identity, truth))}]
    missing = [name for name, method in LEARNED.items() if not _shipped(method)]
    pipelines = {
        f"{prefix}{name}": {"method": method, "use_mask": bool(prefix)}
        for name, method in LEARNED.items()
        if name not in missing
        for prefix in ("", "Mask-")
    }
    timing_pairs = Pairs(*(x[:8] for x in pairs))
    repeats = 3 if ctx.quick else 20
    for name, kwargs in tqdm(pipelines.items(), desc="networks", disable=not ctx.progress):
        rows.append(ctx.row({"pipeline": name}, _network_row, pairs, timing_pairs, repeats, kwargs))
    for row in rows:
        for key in ("ms_per_pair", "ms_mask", "ms_register"):
            row.setdefault(key, float("nan"))

    def plot(path: Path) -> None:
        _error_bars(path, rows, f"Learned back-ends on {len(pairs.template)} ModelNet40 test pairs")

    summary = (
        f"{len(pairs.template)} pairs, the registration experiment's (same seed): 30% missing, "
        "rotation <= 45 deg, translation in [-1, 1]^3; each network at its paper's iteration "
        "count (DCP 1, PRNet 3, PCRNet 8, RPM-Net 5) with the shipped weights; X uses the "
        "whole template, Mask-X the template points MaskNet keeps. Errors from batched calls; "
        f"times: median of {repeats} single-pair register() calls (batch 1) after 2 warm-ups."
        + (f" Not shipped, so not run: {', '.join(missing)}." if missing else "")
    )
    return ExperimentResult(rows, summary, plot)


def exp_iterations(ctx: BenchmarkContext) -> ExperimentResult:
    """Errors after each round of mask -> register -> move the source."""
    pairs = ctx.test_pairs()
    rows = []
    for name, method in (("Mask-ICP", "icp"), ("Mask-PointNetLK", "pointnetlk")):
        kept = ctx.row({"pipeline": name}, _rounds_row, pairs, method, ctx.progress)
        rows += [{"pipeline": name, **row} for row in kept["rounds"]]

    def plot(path: Path) -> None:
        lines = {
            f"{name} ({stat})": [r[f"rot_{stat}"] for r in rows if r["pipeline"] == name]
            for name in ("Mask-ICP", "Mask-PointNetLK")
            for stat in ("mean", "median")
        }
        _line_plot(
            path,
            [1, 2, 3],
            lines,
            "round",
            "rotation error (degrees)",
            "Iterative mask -> register",
        )

    return ExperimentResult(rows, f"{len(pairs.template)} pairs, default protocol, 3 rounds.", plot)


def exp_precision_vs_missing(ctx: BenchmarkContext) -> ExperimentResult:
    """MaskNet's top-k precision as the missing fraction grows (trained at 30%)."""
    model = MaskNet.pretrained()
    missing = [0.1, 0.3, 0.5] if ctx.quick else [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]
    correspondence = [n for n in ("PRNet", "RPM-Net") if _shipped(LEARNED[n])]

    def precisions(miss: float) -> dict:
        config = PairConfig(keep_ratio=1 - miss)
        result = evaluate_masknet(model, ctx.points, ctx.pairs, ctx.seed, config, progress=False)
        top = result.rows["top-k (k=M)"]
        row = {"precision": top["precision"], "recall": top["recall"], "chance": 1 - miss}
        pairs = ctx.test_pairs(config)
        for name in correspondence:
            row[f"{name} precision"] = _correspondence_precision(pairs, LEARNED[name])
        return row

    rows = [ctx.row({"missing": miss}, precisions, miss) for miss in missing]

    def plot(path: Path) -> None:
        lines = {"MaskNet top-k precision": [r["precision"] for r in rows]}
        for name in correspondence:
            lines[f"{name} correspondence precision"] = [r[f"{name} precision"] for r in rows]
        _line_plot(
            path,
            [100 * r["missing"] for r in rows],
            lines,
            "missing points (%)",
            "inlier precision",
            "MaskNet precision vs missing points",
            baseline=("chance (random top-k)", [r["chance"] for r in rows]),
        )

    summary = f"{ctx.pairs} pairs per point, rotation <= 45 deg." + (
        f" {' and '.join(correspondence)}: the share of template points in a confident "
        "correspondence (see RegistrationResult.correspondence_inliers) that are true inliers, "
        "the network on the whole template (no mask)."
        if correspondence
        else ""
    )
    return ExperimentResult(rows, summary, plot)


def _correspondence_precision(pairs: Pairs, method: str, chunk: int = PAIRS_PER_CALL) -> float:
    """Mean per-pair precision of a network's correspondence inliers (pairs with none: 0)."""
    template, source = pairs.template.double().numpy(), pairs.source.double().numpy()
    truth = pairs.mask.numpy()
    precisions = []
    for i in range(0, len(template), chunk):
        result = register(
            template[i : i + chunk], source[i : i + chunk], method=method, use_mask=False
        )
        called = result.correspondence_inliers
        hits = (called & truth[i : i + chunk]).sum(1)
        precisions.append(hits / np.maximum(called.sum(1), 1))
    return float(np.concatenate(precisions).mean())


def _rotated_by(pairs: Pairs, angle_deg: float, seed: int) -> Pairs:
    """Pairs made without rotation, turned by exactly ``angle_deg`` about random axes.

    The source is rotated about the origin, and the truth updated so that
    ``template ~= T @ source`` still holds.
    """
    gen = torch.Generator().manual_seed(seed)
    b = pairs.template.shape[0]
    axes = torch.randn(b, 3, generator=gen, dtype=torch.float64)
    rot = so3_exp(axes / axes.norm(dim=-1, keepdim=True) * np.radians(angle_deg))
    source = pairs.source.double() @ rot.transpose(1, 2)
    moving = make_transform(rot, torch.zeros(b, 3, dtype=torch.float64))
    truth = pairs.transform.double() @ invert_transform(moving)
    return pairs._replace(source=source.float(), transform=truth.float())


def exp_rotation_sweep(ctx: BenchmarkContext) -> ExperimentResult:
    """Errors against the initial rotation, 0-90 degrees, for X and Mask-X."""
    angles = [0, 30, 60, 90] if ctx.quick else list(range(0, 91, 10))
    base = ctx.test_pairs(PairConfig(max_angle_deg=0.0))
    sweep = sweep_pipelines()
    rows = []
    for angle in angles:
        pairs = _rotated_by(base, angle, ctx.seed + angle)
        for name, kwargs in sweep.items():
            rows.append(
                ctx.row({"angle_deg": angle, "pipeline": name}, _batched_errors, pairs, **kwargs)
            )

    def plot(path: Path) -> None:
        lines = {n: [r["rot_mean"] for r in rows if r["pipeline"] == n] for n in sweep}
        _line_plot(
            path,
            angles,
            lines,
            "initial rotation (degrees)",
            "mean rotation error (degrees)",
            "Rotation sweep",
        )

    return ExperimentResult(
        rows, f"{ctx.pairs} pairs per angle, 30% missing, translation in [-1, 1]^3.", plot
    )


PEERS = {
    "Open3D RANSAC (FPFH)": {"method": "open3d-ransac", "use_mask": False},
    "Open3D FGR (FPFH)": {"method": "open3d-fgr", "use_mask": False},
}
PEER_PAIRS = 200  # the global methods take ~0.1 s a pair: sweeps run them on the first 200


def exp_noise(ctx: BenchmarkContext) -> ExperimentResult:
    """Errors against Gaussian noise on the source (sigma 0-0.06, clipped at 0.05)."""
    sigmas = [0.0, 0.02, 0.06] if ctx.quick else [0.0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06]
    rows = []
    for sigma in sigmas:
        config = PairConfig(noise_sigma=sigma, noise_clip=max(0.05, 2 * sigma))
        pairs = ctx.test_pairs(config)
        for name, kwargs in sweep_pipelines().items():
            key = {"sigma": sigma, "pipeline": name}
            rows.append(ctx.row(key, _batched_errors, pairs, **kwargs))
        few = Pairs(*(x[:PEER_PAIRS] for x in pairs))
        for name, kwargs in PEERS.items():
            label = f"{name}, first {len(few.template)} pairs"
            key = {"sigma": sigma, "pipeline": label}
            rows.append(ctx.row(key, _batched_errors, few, **kwargs))

    def plot(path: Path) -> None:
        names = list(dict.fromkeys(r["pipeline"] for r in rows))
        lines = {n: [r["rot_mean"] for r in rows if r["pipeline"] == n] for n in names}
        _line_plot(
            path,
            sigmas,
            lines,
            "noise sigma (unit-radius shapes)",
            "mean rotation error (degrees)",
            "Noise",
        )

    summary = (
        f"{ctx.pairs} pairs per sigma (Open3D's global methods: the first {PEER_PAIRS}), default "
        "protocol otherwise; Gaussian noise on the source, clipped at max(0.05, 2 sigma)."
    )
    return ExperimentResult(rows, summary, plot)


def exp_generalization(ctx: BenchmarkContext) -> ExperimentResult:
    """The model trained on the first 20 categories, on seen and unseen test shapes."""
    model = MaskNet.pretrained("modelnet40_seen20")
    rows = []
    for subset, keep in (("seen", ctx.categories < 20), ("unseen", ctx.categories >= 20)):
        points = ctx.points[keep]
        mask_result = evaluate_masknet(model, points, ctx.pairs, ctx.seed, progress=False)
        pairs = make_test_pairs(points, ctx.pairs, PairConfig(), ctx.seed)
        errors = _batched_errors(pairs, method="pointnetlk", model=model)
        rows.append(
            {
                "categories": subset,
                "precision": mask_result.rows["top-k (k=M)"]["precision"],
                **errors,
            }
        )
    return ExperimentResult(
        rows, f"{ctx.pairs} pairs per subset; Mask-PointNetLK with the seen-20 MaskNet."
    )


def time_pipeline(
    pairs: Pairs, repeats: int, warmup: int = 5, **kwargs: object
) -> dict[str, float]:
    """Median wall time (ms) of single-pair :func:`register` calls, cycling over the pairs,
    with the median time of each stage."""
    template, source = pairs.template.double().numpy(), pairs.source.double().numpy()
    totals, stages = [], {"mask": [], "register": []}
    for call in range(warmup + repeats):
        i = call % len(template)
        start = time.perf_counter()
        result = register(template[i], source[i], **kwargs)
        elapsed = time.perf_counter() - start
        if call >= warmup:
            totals.append(elapsed)
            for key, values in stages.items():
                values.append(result.times[key])
    return {
        "ms_per_pair": 1e3 * float(np.median(totals)),
        **{f"ms_{key}": 1e3 * float(np.median(values)) for key, values in stages.items()},
    }


def exp_timing(ctx: BenchmarkContext) -> ExperimentResult:
    """Milliseconds per pair at batch 1 for X and Mask-X, median of many calls."""
    pairs = ctx.test_pairs(count=8)
    repeats = 5 if ctx.quick else 100
    rows = []
    pipelines = sweep_pipelines() | {
        "ICP (Open3D backend)": {"method": "open3d-icp", "use_mask": False},
        "Mask-ICP (Open3D backend)": {"method": "open3d-icp", "use_mask": True},
    }
    for label, kwargs in pipelines.items():
        method = label.removeprefix("Mask-").removesuffix(" (Open3D backend)")
        paper = PAPER_TIMING_MS.get(method, (float("nan"),) * 2)[label.startswith("Mask-")]
        rows.append(
            {
                "pipeline": label,
                **time_pipeline(pairs, repeats, **kwargs),
                "paper_gtx1070_ms": paper,
            }
        )
    summary = (
        f"batch 1, N=1024, M=717, median of {repeats} single-pair register() calls after 5 "
        f"warm-up calls, {torch.get_num_threads()} threads, {platform.machine()} CPU, "
        f"torch {torch.__version__}; MaskNet in {default_precision('cpu')} (the default)."
    )
    return ExperimentResult(rows, summary)


def _shipped_denoiser() -> MaskNet | None:
    try:
        return MaskNet.pretrained("denoise_modelnet40")
    except MaskNetError:
        return None


def exp_denoising(ctx: BenchmarkContext) -> ExperimentResult:
    """Outlier removal at 5, 10 and 20% uniform outliers: MaskNet (when its denoising
    weights ship), the distance-to-template rule and Open3D's filters."""
    from masknet.denoising import (
        denoise,
        open3d_radius_outlier_removal,
        open3d_statistical_outlier_removal,
    )

    model = _shipped_denoiser()
    rows = []
    for ratio in [0.05, 0.1, 0.2]:
        # Aligned pairs, as the denoiser was trained (denoise after registration).
        pairs = ctx.test_pairs(
            PairConfig(outlier_ratio=ratio, max_angle_deg=0.0, max_translation=0.0)
        )
        noisy, truth = pairs.source.numpy(), pairs.source_mask.numpy()
        templates = pairs.template.numpy()
        methods = {
            "template distance (3x spacing)": np.stack(
                [
                    denoise(c, t, method="distance").mask
                    for c, t in zip(noisy, templates, strict=True)
                ]
            ),
            "Open3D statistical (20 nn, 2 std)": np.stack(
                [open3d_statistical_outlier_removal(c) for c in noisy]
            ),
            "Open3D radius (8 pts in 0.1)": np.stack(
                [open3d_radius_outlier_removal(c) for c in noisy]
            ),
        }
        if model is not None:
            scores = model.predict(noisy, templates, normalize=False)  # unit-radius shapes
            methods = {"MaskNet denoise (threshold 0.5)": scores >= 0.5} | methods
        for name, kept in methods.items():
            rows.append({"outliers": ratio, "method": name, **outlier_removal_metrics(kept, truth)})

    def plot(path: Path) -> None:
        names = list(dict.fromkeys(r["method"] for r in rows))
        lines = {}
        for n in names:
            lines[f"{n}: precision"] = [r["outlier_precision"] for r in rows if r["method"] == n]
            lines[f"{n}: recall"] = [r["outlier_recall"] for r in rows if r["method"] == n]
        _line_plot(
            path,
            [5, 10, 20],
            lines,
            "outliers (% of source points)",
            "outlier removal",
            "Denoising",
        )

    summary = (
        f"{ctx.pairs} pairs per rate: 30% missing source plus uniform outliers in its bounding "
        "box, aligned with the template (no motion: denoising comes after registration); "
        "precision/recall of the removed points as outliers, and the share of real points kept."
    )
    return ExperimentResult(rows, summary, plot)


def _shipped_outlier_masknet() -> MaskNet | None:
    """The MaskNet fine-tuned with 10% uniform outliers in the source, if it ships."""
    try:
        return MaskNet.pretrained("modelnet40_outliers10")
    except MaskNetError:
        return None


def _register_denoise_register(pairs: Pairs, how: dict, kwargs: dict) -> dict[str, float]:
    """Errors of register -> denoise the moved source (``how``: denoise() arguments) ->
    register again, pair by pair."""
    from masknet.denoising import denoise

    truth = pairs.transform.double().numpy()
    estimates = np.empty_like(truth)
    skipped = 0
    for i in range(len(truth)):
        template = pairs.template[i].double().numpy()
        source = pairs.source[i].double().numpy()
        first = register(template, source, **kwargs).transform
        moved = source @ first[:3, :3].T + first[:3, 3]
        cleaned = denoise(moved, template, **how).points
        if len(cleaned) < MIN_POINTS:
            # A first pass far off leaves almost nothing near the template, too few points
            # for register(): keep its estimate.
            estimates[i] = first
            skipped += 1
        else:
            estimates[i] = register(template, cleaned, **kwargs).transform @ first
    return summarize_errors(*pose_errors(estimates, truth)) | {"second_pass_skipped": skipped}


def exp_outliers(ctx: BenchmarkContext) -> ExperimentResult:
    """Registration error against uniform source outliers, 0-20%: X, Mask-X with the shipped
    MaskNet, Mask-X with the MaskNet trained with 10% source outliers (the paper's), and
    Mask-X -> denoise the moved source -> Mask-X again."""
    denoiser = _shipped_denoiser()
    outlier_model = _shipped_outlier_masknet()
    how = {"method": "masknet", "model": denoiser} if denoiser else {"method": "distance"}
    ratios = [0.0, 0.1, 0.2] if ctx.quick else [0.0, 0.05, 0.1, 0.15, 0.2]
    count = ctx.pairs if not ctx.quick else min(ctx.pairs, 10)
    pipelines = dict(SWEEP_PIPELINES)
    if outlier_model is not None:
        for name in ("Mask-ICP", "Mask-PointNetLK"):
            pipelines[f"{name} (MaskNet trained with 10% outliers)"] = {
                **SWEEP_PIPELINES[name],
                "model": outlier_model,
            }
    rows = []
    for ratio in ratios:
        pairs = ctx.test_pairs(PairConfig(outlier_ratio=ratio), count=count)
        for name, kwargs in pipelines.items():
            key = {"outliers": ratio, "pipeline": name}
            rows.append(ctx.row(key, _batched_errors, pairs, **kwargs))
        for name in ("Mask-ICP", "Mask-PointNetLK"):
            key = {"outliers": ratio, "pipeline": f"{name}, denoise ({how['method']}), {name}"}
            rows.append(ctx.row(key, _register_denoise_register, pairs, how, SWEEP_PIPELINES[name]))

    def plot(path: Path) -> None:
        names = list(dict.fromkeys(r["pipeline"] for r in rows))
        lines = {n: [r["rot_mean"] for r in rows if r["pipeline"] == n] for n in names}
        _line_plot(
            path,
            [100 * r for r in ratios],
            lines,
            "outliers (% of source points)",
            "mean rotation error (degrees)",
            "Outliers",
        )

    summary = (
        f"{count} pairs per rate, 30% missing, <= 45 deg; Mask-X uses the shipped MaskNet"
        + (
            ", and the rows marked '(MaskNet trained with 10% outliers)' the MaskNet fine-tuned "
            "with 10% source outliers "
            "(`MaskNet.pretrained('modelnet40_outliers10')`)."
            if outlier_model is not None
            else " (no outlier-trained MaskNet ships)."
        )
        + (
            f" The 'denoise' rows register, drop the source points the denoiser rejects and "
            f"register again; `second_pass_skipped` counts the pairs where fewer than "
            f"{MIN_POINTS} points survived, so the first estimate stands."
        )
    )
    return ExperimentResult(rows, summary, plot)


# (name, template file, source file, ground truth file or None) in ../shared/data/scans.
SCAN_PAIRS = [
    (
        "3DMatch pair (GeoTransformer demo)",
        "geotransformer_demo_ref.npy",
        "geotransformer_demo_src.npy",
        "geotransformer_demo_gt.npy",
    ),
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


def scans_folder() -> Path:
    """``$MASKNET_SCANS``, else ../shared/data/scans beside the working directory."""
    return Path(os.environ.get("MASKNET_SCANS", "../shared/data/scans"))


def exp_scans(ctx: BenchmarkContext) -> ExperimentResult:
    """Zero-shot registration of real scans with the ModelNet40-trained networks."""
    from masknet.io import read_points

    folder = scans_folder()
    if not folder.is_dir():
        raise MaskNetError(
            f"{folder}: scan folder not found; set MASKNET_SCANS to the folder holding the "
            "3DMatch, room, carton and bunny scans (see ../shared/data/README.md)"
        )
    pipelines = {
        "ICP": {"method": "icp", "use_mask": False},
        "Mask-ICP": {"method": "icp", "use_mask": True},
        "PointNetLK": {"method": "pointnetlk", "use_mask": False},
        "Mask-PointNetLK": {"method": "pointnetlk", "use_mask": True},
        "Mask-ICP + 30 ICP refine": {"method": "icp", "use_mask": True, "refine_iterations": 30},
    }
    rows = []
    pairs = SCAN_PAIRS[:1] + SCAN_PAIRS[-1:] if ctx.quick else SCAN_PAIRS
    for title, template_file, source_file, truth_file in pairs:
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
        for name, kwargs in pipelines.items():
            result = register(template, source, **kwargs)
            row = {
                "pair": title,
                "pipeline": name,
                "points": f"{len(template)} / {len(source)}",
                "sampled": f"{result.sampled[0]} / {result.sampled[1]}",
                "ms": 1e3 * result.times["total"],
                "rotation_deg": float(
                    np.degrees(np.arccos(np.clip((np.trace(result.R) - 1) / 2, -1, 1)))
                ),
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


EXPERIMENTS: dict[str, Callable[[BenchmarkContext], ExperimentResult]] = {
    "registration": exp_registration,
    "networks": exp_networks,
    "iterations": exp_iterations,
    "precision-vs-missing": exp_precision_vs_missing,
    "rotation-sweep": exp_rotation_sweep,
    "noise": exp_noise,
    "generalization": exp_generalization,
    "timing": exp_timing,
    "denoising": exp_denoising,
    "outliers": exp_outliers,
    "scans": exp_scans,
}


# ------------------------------------------------------------------------- output


def _format(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}" if abs(value) < 1e4 else f"{value:.0f}"
    return str(value)


def _columns(rows: list[dict]) -> list[str]:
    """Every key of ``rows`` in first-seen order (a column some rows lack stays blank there)."""
    return list(dict.fromkeys(key for row in rows for key in row))


def markdown_table(rows: list[dict]) -> str:
    keys = _columns(rows)
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(_format(r.get(k, "")) for k in keys) + " |" for r in rows]
    return "\n".join(lines)


def _csv_text(rows: list[dict]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=_columns(rows), restval="")
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue()


def update_results(path: Path, name: str, block: str) -> None:
    """Replace (or append) the ``<!-- benchmark:name -->`` block of a markdown file."""
    start, end = f"<!-- benchmark:{name} -->", f"<!-- /benchmark:{name} -->"
    text = path.read_text() if path.exists() else ""
    new = f"{start}\n{block.rstrip()}\n{end}"
    if start in text and end in text:
        text = text[: text.index(start)] + new + text[text.index(end) + len(end) :]
    else:
        text = text.rstrip() + "\n\n" + new + "\n"
    write_text_atomic(path, text)


def run_benchmark(
    name: str, ctx: BenchmarkContext, results: Path | None = None
) -> ExperimentResult:
    """Run one experiment, write its files, and update ``results`` (markdown) if given."""
    if name not in EXPERIMENTS:
        raise MaskNetError(
            f"unknown experiment {name!r}; choose from {', '.join(EXPERIMENTS)} or all"
        )
    ctx.out.mkdir(parents=True, exist_ok=True)
    ctx.start_experiment(name)
    start = time.perf_counter()
    result = EXPERIMENTS[name](ctx)
    wall = time.perf_counter() - start
    reused = dict(ctx.reused)
    stem = ctx.out / name
    payload = {
        "experiment": name,
        "pairs": ctx.pairs,
        "seed": ctx.seed,
        "quick": ctx.quick,
        "wall_time_s": wall,
        "resumed_rows": reused["rows"],  # rows kept from earlier invocations (--resume)
        "resumed_seconds": reused["seconds"],  # what computing those rows took then
        "threads": torch.get_num_threads(),
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, torch {torch.__version__}",
        "summary": result.summary,
        "rows": result.rows,
    }
    write_text_atomic(stem.with_suffix(".json"), json.dumps(payload, indent=2) + "\n")
    write_text_atomic(stem.with_suffix(".csv"), _csv_text(result.rows))
    if result.plot is not None:
        result.plot(stem.with_suffix(".png"))
    if results is not None:
        took = f"{wall / 60:.1f} min"
        if reused["rows"]:
            took += (
                f", plus {reused['seconds'] / 60:.1f} min for {reused['rows']} rows kept from "
                "an interrupted invocation"
            )
        lines = [
            f"`{ctx.command}` ({took}, {payload['machine']}, {payload['threads']} threads)",
            "",
            result.summary,
            "",
            markdown_table(result.rows),
        ]
        if result.plot is not None:
            rel = os.path.relpath(stem.with_suffix(".png"), results.parent)
            lines += ["", f"![{name}]({rel})"]
        update_results(results, name, "\n".join(lines))
    return result


def run_experiments(
    names: list[str],
    ctx: BenchmarkContext,
    results: Path | None = None,
    echo: Callable[[str], None] = lambda line: None,
) -> list[dict]:
    """Run several experiments in order; returns one row each (name, minutes, status).

    An experiment that raises :class:`MaskNetError` (e.g. no scan folder) is skipped
    and the others still run; a single experiment re-raises. With ``results`` and more
    than one experiment, the run's wall times go to its ``benchmark:all`` block.
    """
    start = time.perf_counter()
    log = []
    for name in names:
        tic = time.perf_counter()
        try:
            result = run_benchmark(name, ctx, results)
        except MaskNetError as exc:
            if len(names) == 1:
                raise
            echo(f"== {name}: skipped ({exc})")
            log.append({"experiment": name, "minutes": 0.0, "status": f"skipped: {exc}"})
            continue
        minutes = (time.perf_counter() - tic) / 60
        status = "done"
        if ctx.reused["rows"]:
            status += (
                f"; {ctx.reused['rows']} rows ({ctx.reused['seconds'] / 60:.1f} min) kept from "
                "an interrupted invocation"
            )
        log.append({"experiment": name, "minutes": minutes, "status": status})
        echo(f"== {name} ({60 * minutes:.0f} s): {result.summary}")
        echo(markdown_table(result.rows))
    if results is not None and len(names) > 1:
        wall = (time.perf_counter() - start) / 60
        update_results(
            results,
            "all",
            f"`{ctx.command}`: {wall:.1f} min in all, {torch.get_num_threads()} threads, "
            f"{platform.machine()}, {os.cpu_count()} CPUs, torch {torch.__version__}\n\n"
            + markdown_table(log),
        )
    return log

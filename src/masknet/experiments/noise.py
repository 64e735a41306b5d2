"""``noise``: errors against Gaussian noise on the source."""

from __future__ import annotations

from pathlib import Path

from masknet.data.pairs import PairConfig
from masknet.evaluation.registration import batched_errors
from masknet.experiments.context import BenchmarkContext, ExperimentResult
from masknet.experiments.pipelines import PEER_PAIRS, PEERS, sweep_pipelines
from masknet.experiments.plots import line_plot, series_by


def run(ctx: BenchmarkContext) -> ExperimentResult:
    """Errors against Gaussian noise on the source (sigma 0-0.06, clipped at 0.05)."""
    sigmas = [0.0, 0.06] if ctx.quick else [0.0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06]
    rows = []
    for sigma in sigmas:
        config = PairConfig(noise_sigma=sigma, noise_clip=max(0.05, 2 * sigma))
        pairs = ctx.test_pairs(config)
        for name, kwargs in sweep_pipelines().items():
            key = {"sigma": sigma, "pipeline": name}
            rows.append(ctx.row(key, batched_errors, pairs, **kwargs))
        few = pairs.rows(slice(PEER_PAIRS))
        for name, kwargs in PEERS.items():
            label = f"{name}, first {len(few.template)} pairs"
            key = {"sigma": sigma, "pipeline": label}
            rows.append(ctx.row(key, batched_errors, few, **kwargs))

    def plot(path: Path) -> None:
        line_plot(
            path,
            sigmas,
            series_by(rows, "rot_mean"),
            "noise sigma (unit-radius shapes)",
            "mean rotation error (degrees)",
            "Noise",
        )

    summary = (
        f"{ctx.pairs} pairs per sigma (Open3D's global methods: the first {PEER_PAIRS}), default "
        "protocol otherwise; Gaussian noise on the source, clipped at max(0.05, 2 sigma)."
    )
    return ExperimentResult(rows, summary, plot)

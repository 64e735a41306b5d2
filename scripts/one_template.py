"""Many sources against one template: cold ``register`` calls against the template prepared
once (:func:`masknet.prepare_template`), in this process and through ``register_many``.

    python scripts/one_template.py --sources 200 --out one_template.json
    python scripts/one_template.py --template bunny --sources 40

The sources are partial, moved views of the template: ``PairConfig()`` pairs of one
ModelNet40 test shape (``--data``, ``--shape``), cuts of the Stanford bunny
(``--template bunny``: its first 50-80% along a seeded direction, turned up to 45 degrees),
or the 3DMatch pair's source fragment thinned at random to 50-90% of its points against
its reference fragment (``--template 3dmatch``, the scans beside ``--bunny``).
Timed, each over the same sources: the cold call (``register(template, s)``) and the
prepared one (``register(prepared, s)``), in turn source by source, and ``register_many`` on ``--workers`` processes with
the plain template and with the prepared one (the sources of the one template sent to the
workers in jobs of several, worker start-up included). Reported: the
median seconds per source, the totals, their ratios to the cold loop, and the largest
difference between a prepared call's transform and its cold call's.
"""

from __future__ import annotations

import argparse
import json
import os
import time
import warnings
from pathlib import Path

import numpy as np

from masknet.cli import run_script


def sources_of(args: argparse.Namespace) -> tuple[np.ndarray, list[np.ndarray]]:
    """The template (N, 3) and ``args.sources`` sources (M, 3)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    if args.template == "3dmatch":
        scans = Path(args.bunny).parent
        template = np.load(scans / "geotransformer_demo_ref.npy").astype(np.float64)
        source = np.load(scans / "geotransformer_demo_src.npy").astype(np.float64)
        keep = [rng.uniform(0.5, 0.9) for _ in range(args.sources)]
        return template, [source[rng.random(len(source)) < k] for k in keep]
    if args.template == "bunny":
        from masknet.io import read_points

        template = read_points(args.bunny)
        sources = []
        for _ in range(args.sources):
            along = template @ rng.normal(size=3)
            part = template[along < np.quantile(along, rng.uniform(0.5, 0.8))]
            turn = Rotation.from_rotvec(rng.normal(size=3) * np.pi / 8).as_matrix()
            sources.append(part @ turn.T + rng.uniform(-0.02, 0.02, 3))
        return template, sources
    from masknet.data import PairConfig, load_modelnet40, make_test_pairs

    shapes = load_modelnet40(args.data).points[args.shape : args.shape + 1]
    pairs = make_test_pairs(np.repeat(shapes, args.sources, 0), args.sources, PairConfig(), 0)
    return pairs.template[0].double().numpy(), list(pairs.source.double().numpy())


def timed_in_turn(calls: list, items: list) -> list[tuple[list, list[float]]]:
    """Each of ``calls`` on each item, in turn item by item (a drift of the CPU's speed
    weighs on every call alike): per call, its results and seconds for each item."""
    out: list[tuple[list, list[float]]] = [([], []) for _ in calls]
    for item in items:
        for call, (results, seconds) in zip(calls, out, strict=True):
            tic = time.perf_counter()
            results.append(call(item))
            seconds.append(time.perf_counter() - tic)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sources", type=int, default=200)
    parser.add_argument(
        "--template", choices=("modelnet40", "bunny", "3dmatch"), default="modelnet40"
    )
    parser.add_argument("--data", default=os.environ.get("DATA"), help="ModelNet40 .npz")
    parser.add_argument("--shape", type=int, default=7, help="the ModelNet40 test shape")
    parser.add_argument(
        "--bunny",
        default=str(
            Path(__file__).resolve().parents[1] / "../shared/data/scans/bun_zipper_res3.ply"
        ),
    )
    parser.add_argument("--workers", type=int, default=2, help="register_many's; 0: skip it")
    parser.add_argument("--out", help="write the figures here (.json)")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    from masknet import prepare_template, register, register_many

    template, sources = sources_of(args)
    register(template, sources[0])  # the networks' weights, loaded once
    tic = time.perf_counter()
    prepared = prepare_template(template)
    prepare_seconds = time.perf_counter() - tic
    (cold, cold_each), (warm, warm_each) = timed_in_turn(
        [lambda s: register(template, s), lambda s: register(prepared, s)], sources
    )
    cold_total, warm_total = sum(cold_each), sum(warm_each)
    gaps = [float(np.abs(a.transform - b.transform).max()) for a, b in zip(cold, warm, strict=True)]
    out = {
        "template": args.template,
        "template_points": len(template),
        "sources": len(sources),
        "paths": {
            p: sum(r.info["path"] == p for r in cold) for p in {r.info["path"] for r in cold}
        },
        "cold_median_s": float(np.median(cold_each)),
        "cold_total_s": cold_total,
        "prepare_s": prepare_seconds,
        "prepared_median_s": float(np.median(warm_each)),
        "prepared_total_s": warm_total,
        "prepared_median_ratio": float(np.median(warm_each) / np.median(cold_each)),
        "prepared_total_ratio": warm_total / cold_total,
        "views_cached": prepared.views,
        "max_transform_difference": max(gaps),
        "identical_poses": sum(g == 0.0 for g in gaps),
    }
    if args.workers:
        for name, first in (("many_cold", template), ("many_prepared", prepared)):
            tic = time.perf_counter()
            results = register_many([(first, s) for s in sources], workers=args.workers)
            out[f"{name}_total_s"] = time.perf_counter() - tic
            out[f"{name}_total_ratio"] = out[f"{name}_total_s"] / cold_total
            out[f"{name}_max_transform_difference"] = max(
                float(np.abs(r.transform - c.transform).max())
                for r, c in zip(results, cold, strict=True)
            )
    print(json.dumps(out, indent=1))
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    run_script(main)

"""Ship a training run's best weights inside the package, with a measured model card.

    python scripts/ship.py masknet runs/modelnet40 modelnet40 --data PATH
    python scripts/ship.py masknet runs/seen20 modelnet40_seen20 --data PATH
    python scripts/ship.py masknet runs/ft modelnet40 --data PATH --previous OLD_CARD.json
    python scripts/ship.py crossmasknet relay/crossmasknet_fpfh_modelnet40 modelnet40 --data PATH
    python scripts/ship.py denoise runs/denoise denoise_modelnet40 --data PATH
    python scripts/ship.py refine runs/refinemask_scans scans --data PATH --eval-scans DIR
    python scripts/ship.py pointnetlk runs/pointnetlk modelnet40 --data PATH
    python scripts/ship.py dcp runs/dcp modelnet40 --data PATH  (prnet, pcrnet, rpmnet)

The subcommand is the kind of weights. Every figure on the card comes from the run
folder (run.json, log.csv) or is measured here on ``--pairs`` (default 1,000) seeded
ModelNet40 *test* pairs; nothing is typed by hand. ``--previous`` names the card of
the weights a run was started from (``masknet train --init``), so the card states
the whole training. The cards are rendered by :mod:`masknet.cards`.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
import torch

from masknet import cards, cross_card
from masknet.cli import run_script
from masknet.data import PairConfig, load_modelnet40, make_test_pairs
from masknet.denoising import open3d_radius_outlier_removal, open3d_statistical_outlier_removal
from masknet.evaluation.evaluate import evaluate_masknet, format_table
from masknet.evaluation.registration import batched_errors, error_summary
from masknet.metrics import outlier_removal_metrics
from masknet.models import REGISTRATION_NETWORKS, CrossMaskNet, MaskNet

WEIGHTS = Path(__file__).resolve().parents[1] / "src" / "masknet" / "resources" / "weights"


def install(run: Path, filename: str, card: dict, markdown: str) -> None:
    """Copy the run's best weights into the package, with the card as JSON and markdown."""
    WEIGHTS.mkdir(parents=True, exist_ok=True)
    stem = Path(filename).stem
    shutil.copyfile(run / "best.safetensors", WEIGHTS / filename)
    (WEIGHTS / f"{stem}.json").write_text(json.dumps(card, indent=2) + "\n")
    (WEIGHTS / f"{stem}.md").write_text(markdown)
    print(f"wrote {WEIGHTS / filename} and its model card")


def ship_masknet(args: argparse.Namespace, previous: dict | None) -> None:
    """MaskNet: mask metrics on all, seen and unseen test categories."""
    run, log = cards.read_run(args.run)
    model = MaskNet.from_file(args.run / "best.safetensors")
    best = max(log, key=lambda row: float(row["val_precision"]))
    test = load_modelnet40(args.data, "test")
    pair_config = PairConfig(**run["task"]["pairs"])
    evaluations = {}
    for subset in ("all", "seen", "unseen"):
        points = test.subset(subset).points
        evaluations[subset] = evaluate_masknet(model, points, args.pairs, args.seed, pair_config)
        print(subset, format_table(evaluations[subset].rows), sep="\n")

    test_results = {subset: ev.to_dict() for subset, ev in evaluations.items()}
    card = cards.base_card(args.name, run, log, model.config, best, test_results, previous)
    if "scans" in run["task"]:
        card["scans_test"] = scan_results(model, run, args)
    if args.note:
        card["note"] = args.note
    if model.config != MaskNet().config:
        card["speed"] = inference_times(model)
        print("inference ms", card["speed"]["ms"])
    install(args.run, f"masknet_{args.name}.safetensors", card, cards.render_masknet_card(card))


def ship_crossmasknet(args: argparse.Namespace, previous: dict | None) -> None:
    """CrossMaskNet: stored in fp16 where that keeps the fp32 weights' top-k labels (as
    ``scripts/weights_storage.py`` decides), else fp32; then the shipped weights' mask
    metrics on the test pairs and their time at batch 1 beside the paper's MaskNet."""
    import tempfile

    from weights_storage import MIN_AGREEMENT, rounded_copy

    from masknet.evaluation.evaluate import evaluate_pairs
    from masknet.models.masknet import select_mask
    from masknet.models.weights import read_metadata

    run, log = cards.read_run(args.run)
    model = CrossMaskNet.from_file(args.run / "best.safetensors")
    best = max(log, key=lambda row: float(row["val_precision"]))
    pair_config = PairConfig(**run["task"]["pairs"])
    test = load_modelnet40(args.data, "test").points
    pairs = make_test_pairs(test, args.pairs, pair_config, args.seed)
    half = rounded_copy(model, torch.float16)
    evaluations, masks = {}, {}
    for storage, network in (("fp32", model), ("fp16", half)):
        evaluations[storage] = evaluate_pairs(
            network, pairs, args.seed, pair_config.to_dict(), keep_outputs=True
        )
        scores = torch.from_numpy(evaluations[storage].scores)
        masks[storage] = select_mask(scores, k=pairs.source.shape[1]).numpy()
    agreement = float((masks["fp16"] == masks["fp32"]).mean())
    storage = "fp16" if agreement >= MIN_AGREEMENT else "fp32"
    shipped, evaluation = (half if storage == "fp16" else model), evaluations[storage]
    print(f"fp16 top-k label agreement {agreement:.5f}: storing {storage}", flush=True)
    print(format_table(evaluation.rows), flush=True)
    card = cards.base_card(args.name, run, log, model.config, best, {}, previous)
    card["test"] = {"all": evaluation.to_dict()}
    card["storage"] = {"dtype": storage, "fp16_point_agreement": agreement}
    card["storage"] |= {"min_agreement": MIN_AGREEMENT, "pairs": args.pairs}
    card["speed"] = inference_times(shipped)
    card["version"] = args.version
    print("inference ms", card["speed"]["ms"])
    held = read_metadata(args.run / "best.safetensors")  # save() writes config and storage
    kept = {k: v for k, v in held.items() if not k.endswith("config") and k != "storage"}
    with tempfile.TemporaryDirectory() as folder:  # the file shipped: save() with its storage
        shipped.save(Path(folder) / "best.safetensors", kept, storage=storage)
        markdown = cross_card.render_crossmasknet_card(card)
        install(
            Path(folder), f"{CrossMaskNet.weights_prefix}{args.name}.safetensors", card, markdown
        )


def inference_times(model: MaskNet, repeats: int = 30) -> dict:
    """Median ms of one ``predict_mask`` call (fp32) for 512 and 1,024 template points (a
    source of 70% of them), this network and the paper's, on this machine's torch threads."""
    import time

    from masknet.runtime import cpu_name

    paper = MaskNet.pretrained("modelnet40")
    rng = np.random.default_rng(0)
    out = {}
    for points in (512, 1024):
        template = rng.normal(size=(points, 3)).astype(np.float32)
        source = template[: int(0.7 * points)]
        ms = {}
        for label, network in (("this", model), ("paper", paper)):
            network.predict_mask(template, source, precision="fp32")  # warm-up
            times = []
            for _ in range(repeats):
                tic = time.perf_counter()
                network.predict_mask(template, source, precision="fp32")
                times.append(1e3 * (time.perf_counter() - tic))
            ms[label] = float(np.median(times))
        out[str(points)] = ms
    machine = f"{cpu_name()}, torch {torch.__version__}"
    return {"ms": out, "repeats": repeats, "threads": torch.get_num_threads(), "machine": machine}


def scan_results(model: MaskNet, run: dict, args: argparse.Namespace) -> dict:
    """Mask metrics on pairs cut from the run's held-out scans (``--scans``: the training
    folder) and from ``--eval-scans`` (a folder never trained on), 0.2% noise."""
    from masknet.data.scans import load_scans
    from masknet.data.views import ViewConfig
    from masknet.evaluation.scans import evaluate_scans

    stored = run["task"]["view"]
    changes = {"noise_sigma": 0.002, "random_noise": False}
    view = ViewConfig(**(stored | changes | {"view_distance": tuple(stored["view_distance"])}))
    sets = {}
    if args.scans:
        held = [s for s in load_scans(args.scans) if s.name in run["task"]["val_scans"]]
        sets["held-out training scans"] = held
    if args.eval_scans:
        sets["evaluation scans"] = load_scans(args.eval_scans)
    out = {}
    for label, scans in sets.items():
        result = evaluate_scans(model, scans, args.pairs_per_scan, args.seed, view, pipelines=None)
        out[label] = result.to_dict() | {"folder_scans": [s.name for s in scans]}
        print(label, format_table(result.mask.rows), sep="\n")
    return out


def ship_denoise(args: argparse.Namespace, previous: dict | None) -> None:
    """Denoising MaskNet: outlier removal at 5, 10 and 20% uniform outliers, threshold 0.5,
    beside Open3D's statistical and radius outlier removal."""
    run, log = cards.read_run(args.run)
    model = MaskNet.from_file(args.run / "best.safetensors")
    test = load_modelnet40(args.data, "test").points
    base = run["task"]["pairs"]
    results = {}
    for ratio in (0.05, 0.1, 0.2):
        pairs = make_test_pairs(
            test, args.pairs, PairConfig(**(base | {"outlier_ratio": ratio})), args.seed
        )
        noisy, real = pairs.source.numpy(), pairs.source_mask.numpy()
        scores = model.predict(noisy, pairs.template.numpy(), precision="fp32", normalize=False)
        results[f"{ratio:.0%}"] = {
            "MaskNet (threshold 0.5)": outlier_removal_metrics(scores >= 0.5, real),
            "Open3D statistical (20, 2.0)": outlier_removal_metrics(
                np.stack([open3d_statistical_outlier_removal(c) for c in noisy]), real
            ),
            "Open3D radius (8, 0.1)": outlier_removal_metrics(
                np.stack([open3d_radius_outlier_removal(c) for c in noisy]), real
            ),
        }
        print(ratio, results[f"{ratio:.0%}"])
    best = max(log, key=lambda row: float(row["val_f1"]))
    test = {"pairs": args.pairs, "seed": args.seed, "results": results}
    card = cards.base_card(args.name, run, log, model.config, best, test, previous)
    install(args.run, f"masknet_{args.name}.safetensors", card, cards.render_denoise_card(card))


def ship_refine(args: argparse.Namespace, previous: dict | None) -> None:
    """Refinement mask: against the nearest-neighbour rule at fixed residual rotations, on
    ModelNet40 test pairs (clean, noise, outliers, sensor-like views) and pairs
    cut from ``--eval-scans`` (with and without shared points)."""
    import os
    import tempfile

    from masknet.experiments.context import BenchmarkContext
    from masknet.experiments.rounds import refiner_table
    from masknet.models.refine import RefineMaskNet
    from masknet.registration.stages.refinement import NearestNeighbourMasks

    run, log = cards.read_run(args.run)
    model = RefineMaskNet.from_file(args.run / "best.safetensors")
    if args.eval_scans:
        os.environ["MASKNET_SCANS"] = args.eval_scans
    out = Path(tempfile.mkdtemp())  # the row cache of the shared experiment code
    ctx = BenchmarkContext(
        data=args.data, pairs=args.pairs, seed=args.seed, progress=False, out=out
    )
    refiners = {"rule": NearestNeighbourMasks(), "learned": model}
    rows = refiner_table(ctx, refiners, args.pairs, args.pairs_per_scan)
    for row in rows:
        print(row)
    best = max(log, key=lambda row: float(row["val_score"]))
    test = {"pairs": args.pairs, "pairs_per_scan": args.pairs_per_scan, "seed": args.seed}
    test["rows"] = rows
    card = cards.base_card(args.name, run, log, model.config, best, test, previous)
    card["parameters"] = sum(p.numel() for p in model.parameters())
    card["version"] = args.version
    if args.note:
        card["note"] = args.note
    install(args.run, f"refinemask_{args.name}.safetensors", card, cards.render_refine_card(card))


def ship_network(args: argparse.Namespace, previous: dict | None) -> None:
    """A registration network beside the same architecture at its starting (untrained,
    seeded) weights and beside identity (no motion), on the network's training protocol
    and the default 30%-missing one, where Mask-X (the shipped MaskNet) is measured too."""
    method = args.kind
    cls = REGISTRATION_NETWORKS[method]
    run, log = cards.read_run(args.run)
    trained = cls.from_file(args.run / "best.safetensors").eval()
    torch.manual_seed(run["train"]["seed"])  # the loop's seeding: the starting weights
    untrained = cls(**trained.config).eval()
    test = load_modelnet40(args.data, "test").points
    protocols = {
        f"training protocol (keep ratio {run['task']['pairs']['keep_ratio']})": PairConfig(
            **run["task"]["pairs"]
        ),
        "30% missing (default protocol)": PairConfig(),
    }

    def errors(network: torch.nn.Module, pairs, use_mask: bool = False) -> dict:
        return batched_errors(pairs, chunk=100, method=method, use_mask=use_mask, network=network)

    results = {}
    for label, config in protocols.items():
        pairs = make_test_pairs(test, args.pairs, config, args.seed)
        truth = pairs.transform.double().numpy()
        results[label] = {
            "trained": errors(trained, pairs),
            "untrained (starting weights)": errors(untrained, pairs),
            "identity (no motion)": error_summary(np.broadcast_to(np.eye(4), truth.shape), truth),
        }
        if label.startswith("30%"):
            results[label]["trained, Mask-X"] = errors(trained, pairs, use_mask=True)
        print(label, results[label], flush=True)
    best = min(log, key=lambda row: float(row["val_rotation_error_deg"]))
    test = {"pairs": args.pairs, "seed": args.seed, "results": results}
    card = cards.base_card(args.name, run, log, trained.config, best, test, previous)
    markdown = cards.render_network_card(card, method)
    install(args.run, f"{cls.weights_prefix}{args.name}.safetensors", card, markdown)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="kind", required=True)
    for kind in ("masknet", "crossmasknet", "denoise", "refine", *REGISTRATION_NETWORKS):
        p = sub.add_parser(kind, help=f"ship {kind} weights")
        p.add_argument("run", type=Path, help="the training run folder")
        p.add_argument("name", help="name of the shipped weights, e.g. modelnet40")
        p.add_argument("--data", required=True)
        p.add_argument("--pairs", type=int, default=1000)
        p.add_argument("--seed", type=int, default=0)
        p.add_argument("--previous", type=Path, help="card (.json) of the --init weights")
        p.add_argument("--scans", help="masknet: the --scans folder of the run (held-out scans)")
        p.add_argument("--eval-scans", help="masknet, refine: a folder of scans never trained on")
        p.add_argument("--pairs-per-scan", type=int, default=100)
        p.add_argument(
            "--version", default="1.0", help="refine, crossmasknet: the version on the card"
        )
        p.add_argument(
            "--note", help="masknet, refine: a line for the card that the run cannot tell"
        )
        p.add_argument(
            "--previous-run",
            type=Path,
            help="run folder of the --init weights, when they have no card",
        )
    args = parser.parse_args()
    previous = json.loads(args.previous.read_text()) if args.previous else None
    if args.previous_run:
        previous = cards.run_summary(args.previous_run)
    ship = {
        "masknet": ship_masknet,
        "crossmasknet": ship_crossmasknet,
        "denoise": ship_denoise,
        "refine": ship_refine,
    }.get(args.kind, ship_network)
    ship(args, previous)


if __name__ == "__main__":
    run_script(main)

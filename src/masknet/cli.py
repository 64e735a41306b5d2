"""The ``masknet`` command: a thin layer over the Python API.

Every failure caused by input (missing file, bad format, NaN rows, wrong shape)
is printed as one line, ``masknet: error: <file>: <problem>``, with exit code 2.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

from masknet.errors import MaskNetError

__all__ = ["main", "build_parser"]


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def _seed(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be non-negative, got {value}")
    return value


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


def _json_object(text: str) -> dict:
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"not valid JSON ({exc.msg}): {text}") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"must be a JSON object, got {text}")
    return value


def _add_pair_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("pair generation")
    g.add_argument(
        "--protocol",
        choices=["paper", "official"],
        default="paper",
        help="paper: random viewpoint, angle in [0, max-angle], translation in the cube; "
        "official: the authors' code (768 points, twist <= 0.8)",
    )
    g.add_argument(
        "--keep-ratio",
        type=float,
        default=None,
        help="fraction of template points the source keeps (default 0.7; "
        "1.0 when training pointnetlk, which trains on full clouds)",
    )
    g.add_argument("--max-angle", type=float, default=45.0, help="maximum rotation, degrees")
    g.add_argument("--max-translation", type=float, default=1.0, help="translation range per axis")
    g.add_argument(
        "--noise",
        type=float,
        default=0.0,
        help="Gaussian noise sigma on the source (clipped at 0.05)",
    )
    g.add_argument(
        "--outliers",
        type=float,
        default=None,
        help="fraction of uniform outliers added (default 0; 0.1 when training denoise)",
    )
    g.add_argument("--outlier-target", choices=["source", "template"], default="source")
    g.add_argument(
        "--categories",
        choices=["all", "seen", "unseen"],
        default="all",
        help="all 40, the first 20 (seen) or the last 20 (unseen) categories, alphabetical",
    )


def _pair_config(
    args: argparse.Namespace, default_keep_ratio: float = 0.7, default_outliers: float = 0.0
):
    from masknet.data import PairConfig

    keep = default_keep_ratio if args.keep_ratio is None else args.keep_ratio
    outliers = default_outliers if args.outliers is None else args.outliers
    try:
        return PairConfig(
            keep_ratio=keep,
            max_angle_deg=args.max_angle,
            max_translation=args.max_translation,
            noise_sigma=args.noise,
            outlier_ratio=outliers,
            outlier_target=args.outlier_target,
            protocol=args.protocol,
        )
    except ValueError as exc:
        raise MaskNetError(str(exc)) from None


def build_parser() -> argparse.ArgumentParser:
    from masknet import __version__

    parser = argparse.ArgumentParser(
        prog="masknet",
        description="MaskNet: predict which template points a partial source cloud also sees.",
    )
    parser.add_argument("--version", action="version", version=f"masknet {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser(
        "train",
        help="train MaskNet or a registration network on ModelNet40 (CPU or GPU), resumable",
    )
    p.add_argument(
        "--model",
        choices=["masknet", "denoise", "pointnetlk", "dcp", "prnet", "pcrnet", "rpmnet"],
        default="masknet",
        help="masknet (partial pairs), denoise (MaskNet scoring the points of a source "
        "with outliers, 10%% by default), or a registration network: pointnetlk, dcp, "
        "pcrnet (full-cloud pairs, as their papers train) or prnet, rpmnet (partial pairs)",
    )
    p.add_argument("--data", help="ModelNet40 folder or .npz (default: $MASKNET_DATA)")
    p.add_argument(
        "--out", required=True, help="run folder: checkpoint.pt, log.csv, best.safetensors"
    )
    p.add_argument("--epochs", type=_positive_int, default=100)
    p.add_argument("--batch-size", type=_positive_int, default=32)
    p.add_argument("--lr", type=float, default=1e-4)
    p.add_argument("--lr-schedule", choices=["constant", "cosine"], default="constant")
    p.add_argument("--loss", choices=["mse", "bce"], default="mse", help="masknet only")
    p.add_argument(
        "--feature-size",
        type=_positive_int,
        help="PointNet feature size K (last encoder width); default 1024",
    )
    p.add_argument(
        "--iterations",
        "--lk-iterations",
        dest="iterations",
        type=_positive_int,
        help="registration networks: refinement iterations per training pair (default: "
        "pointnetlk 10, dcp 1, pcrnet 3, prnet 2, rpmnet 2)",
    )
    p.add_argument(
        "--model-config",
        type=_json_object,
        default=None,
        metavar="JSON",
        help="registration networks: keyword arguments of the network class, e.g. "
        '\'{"embedding": 128, "k": 16}\' for dcp (default: the paper\'s sizes)',
    )
    p.add_argument(
        "--precision",
        choices=["auto", "fp32", "bf16"],
        default="auto",
        help="autocast dtype; auto = bf16 where the hardware has it (masknet only: the "
        "registration networks train in fp32)",
    )
    p.add_argument(
        "--num-points", type=_positive_int, default=1024, help="template points per training pair"
    )
    p.add_argument(
        "--val-fraction", type=float, default=0.1, help="training shapes held out for validation"
    )
    p.add_argument(
        "--val-pairs",
        type=_positive_int,
        default=512,
        help="validation pairs made from those shapes",
    )
    p.add_argument("--seed", type=_seed, default=0)
    p.add_argument("--device", default="auto")
    p.add_argument("--threads", type=_positive_int, help="torch CPU threads")
    p.add_argument(
        "--max-minutes",
        type=float,
        help="minutes for this invocation: no epoch starts that would end past it",
    )
    p.add_argument("--resume", action="store_true", help="continue the checkpoint in --out")
    p.add_argument("--init", help="start from these weights (.safetensors), e.g. to fine-tune")
    _add_pair_options(p)

    p = sub.add_parser(
        "evaluate", help="mask precision/recall/F1/IoU on seeded ModelNet40 test pairs"
    )
    p.add_argument("--data", help="ModelNet40 folder or .npz (default: $MASKNET_DATA)")
    p.add_argument("--pairs", type=_positive_int, default=1000)
    p.add_argument("--seed", type=_seed, default=0)
    p.add_argument("--json", help="also write the results to this JSON file")
    p.add_argument(
        "--realign-rounds",
        type=_positive_int,
        default=1,
        metavar="R",
        help="also report the top-k mask predicted in round R of mask -> Mask-ICP (30 "
        "iterations) -> move the source: MaskNet inside the iterative pipeline",
    )
    _add_model_options(p)
    _add_pair_options(p)

    p = sub.add_parser(
        "mask", help="predict which TEMPLATE points SOURCE sees; write them and the mask"
    )
    p.add_argument("template", help="full cloud: .ply .pcd .xyz .txt .npy .bin")
    p.add_argument("source", help="partial cloud of the same object")
    p.add_argument(
        "-o",
        "--output",
        required=True,
        help="inlier template points (format from the extension); the mask goes to "
        "<stem>_mask.txt beside it, one 0/1 per template point",
    )
    sel = p.add_mutually_exclusive_group()
    sel.add_argument(
        "--k", type=_positive_int, help="keep the k highest scores (default: k = source points)"
    )
    sel.add_argument(
        "--threshold", type=_finite_float, help="keep scores >= this (the paper's epsilon)"
    )
    _add_file_options(p)
    _add_model_options(p)

    p = sub.add_parser(
        "register",
        help="align SOURCE to TEMPLATE (Mask-X, or plain X with --no-mask); write the "
        "moved source, the 4x4 transform and the inlier template",
    )
    p.add_argument("template", help="full cloud: .ply .pcd .xyz .txt .npy .bin")
    p.add_argument("source", help="partial cloud of the same object, any pose")
    p.add_argument(
        "-o",
        "--output",
        required=True,
        help="the registered source (format from the extension); beside it "
        "<stem>_transform.txt (4x4, source -> template) and, with a mask, "
        "<stem>_inliers<ext> (the template points used)",
    )
    p.add_argument(
        "--method",
        choices=[
            "icp",
            "open3d-icp",
            "pointnetlk",
            "dcp",
            "prnet",
            "pcrnet",
            "rpmnet",
            "open3d-ransac",
            "open3d-fgr",
        ],
        default="icp",
        help="icp (default), a learned network (pointnetlk, dcp, prnet, pcrnet, rpmnet; "
        "shipped weights unless --network-weights), or Open3D's icp / RANSAC / FGR on FPFH",
    )
    p.add_argument(
        "--network-weights",
        metavar="PATH",
        help="weights (.safetensors from masknet train --model NAME) for a learned --method",
    )
    p.add_argument("--no-mask", action="store_true", help="plain X instead of Mask-X")
    p.add_argument("--iterations", type=_positive_int, default=1, help="rounds of mask -> register")
    p.add_argument(
        "--max-iterations",
        type=_positive_int,
        default=None,
        help="iterations of the method per round (default: 10 for ICP and PointNetLK, "
        "as the paper; the learned networks' own: dcp 1, prnet 3, pcrnet 8, rpmnet 5)",
    )
    p.add_argument(
        "--refine",
        type=int,
        default=0,
        metavar="N",
        help="end with N iterations of plain ICP on the whole template (default 0)",
    )
    p.add_argument("--init", choices=["centroid", "identity"], default="centroid")
    p.add_argument(
        "--max-points",
        type=_positive_int,
        default=1024,
        help="larger clouds are farthest-point sampled to this for the networks and "
        "ICP; the transform is applied to the full source",
    )
    _add_file_options(p)
    _add_model_options(p)

    p = sub.add_parser(
        "denoise",
        help="remove the points of NOISY that TEMPLATE (a clean cloud of the same object) "
        "does not explain",
    )
    p.add_argument("noisy", help="the scan with outliers: .ply .pcd .xyz .txt .npy .bin")
    p.add_argument(
        "template",
        help="a clean cloud of the same object, aligned with NOISY (e.g. after register)",
    )
    p.add_argument(
        "-o",
        "--output",
        required=True,
        help="the kept points (format from the extension); <stem>_mask.txt beside it, "
        "one 0/1 per noisy point",
    )
    p.add_argument(
        "--method",
        choices=["distance", "masknet"],
        default="distance",
        help="distance (default): keep points near the template; masknet: a denoising "
        "network (--weights from masknet train --model denoise)",
    )
    p.add_argument(
        "--threshold", type=_finite_float, default=0.5, help="masknet: keep points scoring >= this"
    )
    p.add_argument(
        "--max-distance",
        type=_finite_float,
        help="distance: the largest distance kept, in the clouds' units "
        "(default 3x the template's point spacing)",
    )
    _add_file_options(p)
    _add_model_options(p, default_pretrained="denoise_modelnet40")

    p = sub.add_parser(
        "show",
        help="write an interactive 3D view (one offline HTML file) and a PNG of clouds",
    )
    p.add_argument("clouds", nargs="+", help="point cloud files, one layer each")
    p.add_argument("-o", "--output", required=True, help="the .html file; the PNG goes beside it")
    p.add_argument("--title", default=None)
    _add_file_options(p, html=False)

    p = sub.add_parser(
        "benchmark",
        help="reproduce the paper's experiments on seeded ModelNet40 test pairs: "
        "table (JSON, CSV), plot (PNG) and docs/RESULTS.md",
    )
    p.add_argument(
        "experiment",
        help="registration, networks, iterations, precision-vs-missing, rotation-sweep, "
        "noise, generalization, timing, denoising, outliers, scans, or all",
    )
    p.add_argument("--data", help="ModelNet40 folder or .npz (default: $MASKNET_DATA)")
    p.add_argument("--pairs", type=_positive_int, help="pairs per setting (default 1000)")
    p.add_argument("--seed", type=_seed, default=0)
    p.add_argument(
        "--quick",
        action="store_true",
        help="a small run (20 pairs, fewer settings; the bundled sample when no data is "
        "given); leaves docs/RESULTS.md alone",
    )
    p.add_argument("--out", default="masknet_benchmark", help="folder for JSON, CSV and PNG")
    p.add_argument(
        "--results",
        default="docs/RESULTS.md",
        help="markdown file whose benchmark blocks are rewritten (default docs/RESULTS.md, "
        "when it exists); 'none' to skip",
    )
    p.add_argument("--threads", type=_positive_int, help="torch CPU threads")
    p.add_argument(
        "--resume",
        action="store_true",
        help="after a kill: keep the table rows the interrupted run already wrote to "
        "--out/.rows (same pairs, seed, weights, data and version) and compute the rest",
    )

    p = sub.add_parser(
        "demo", help="run the shipped model on the bundled sample: metrics and a picture"
    )
    p.add_argument("--out", default="masknet_demo", help="folder for the picture and metrics")
    p.add_argument("--pairs", type=_positive_int, default=240)
    p.add_argument("--seed", type=_seed, default=0)
    _add_model_options(p)

    p = sub.add_parser(
        "make-sample", help="rebuild the bundled sample from the ModelNet40 test split"
    )
    p.add_argument("--data", help="ModelNet40 folder or .npz (default: $MASKNET_DATA)")
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--per-class", type=_positive_int, default=3)
    return parser


def _add_file_options(p: argparse.ArgumentParser, html: bool = True) -> None:
    """Options of every command that reads clouds from files (and optionally shows them)."""
    p.add_argument(
        "--drop-nonfinite", action="store_true", help="drop NaN/inf rows instead of failing"
    )
    if html:
        p.add_argument(
            "--html",
            metavar="PATH",
            help="also write an interactive 3D view (offline HTML) here, and a PNG beside it",
        )


def _write_views(path: str, layers: dict, title: str) -> list[Path]:
    """The HTML viewer and its static PNG twin, for --html and show."""
    from masknet.viewer import LAYER_COLOURS, write_viewer
    from masknet.viz import plot_clouds

    html = write_viewer(path, layers, title=title)
    coloured = {
        name: layer if isinstance(layer, tuple) else (layer, LAYER_COLOURS.get(name, "#1f77b4"))
        for name, layer in layers.items()
    }
    png = plot_clouds(coloured, Path(path).with_suffix(".png"), title=title)
    return [html, png]


def _add_model_options(p: argparse.ArgumentParser, default_pretrained: str = "modelnet40") -> None:
    g = p.add_argument_group("model")
    g.add_argument(
        "--weights", help="a .safetensors file from masknet train (default: shipped weights)"
    )
    g.add_argument(
        "--pretrained",
        default=default_pretrained,
        help=f"name of shipped MaskNet weights (default {default_pretrained})",
    )
    g.add_argument(
        "--inference-precision",
        choices=["auto", "fp32", "bf16"],
        default="auto",
        help="auto: bf16 where the CPU/GPU runs it natively (mask agreement 99.7%% with fp32), "
        "else fp32",
    )


def _load_model(args: argparse.Namespace):
    from masknet.models import MaskNet
    from masknet.runtime import default_precision

    if args.inference_precision == "auto":
        args.inference_precision = default_precision("cpu")

    return MaskNet.from_file(args.weights) if args.weights else MaskNet.pretrained(args.pretrained)


def cmd_train(args: argparse.Namespace) -> None:
    from masknet.data import load_modelnet40
    from masknet.models import REGISTRATION_NETWORKS, MaskNet
    from masknet.training import TRAINING_DEFAULTS, MaskNetTask, RegistrationTask, TrainConfig, fit

    data = load_modelnet40(args.data, "train").subset(args.categories)
    if not 16 <= args.num_points <= data.points.shape[1]:
        raise MaskNetError(
            f"--num-points must be in [16, {data.points.shape[1]}], got {args.num_points}"
        )
    encoder = {}
    if args.feature_size:
        encoder = {"encoder_channels": [64, 64, 64, 128, args.feature_size]}
    precision = args.precision
    if args.model == "denoise":
        task = MaskNetTask.denoising(
            _pair_config(args, default_outliers=0.1),
            num_points=args.num_points,
            loss=args.loss,
            model_config=encoder,
        )
        model_class = MaskNet
    elif args.model == "masknet":
        task = MaskNetTask(
            pairs=_pair_config(args),
            num_points=args.num_points,
            loss=args.loss,
            model_config=encoder,
        )
        model_class = MaskNet
    else:
        defaults = TRAINING_DEFAULTS[args.model]
        model_config = args.model_config if args.model_config is not None else encoder
        task = RegistrationTask(
            pairs=_pair_config(args, default_keep_ratio=defaults["keep_ratio"]),
            num_points=args.num_points,
            name=args.model,
            iterations=args.iterations or defaults["iterations"],
            model_config=model_config,
        )
        model_class = REGISTRATION_NETWORKS[args.model]
        try:
            task.build_model()
        except TypeError as exc:
            raise MaskNetError(f"--model-config does not fit {args.model}: {exc}") from None
        if precision == "bf16":
            raise MaskNetError(
                f"--precision bf16 does not suit {args.model}: registration networks train "
                "in fp32 (PointNetLK's finite-difference Jacobian and the SVDs need it)"
            )
        precision = "fp32"
    config = TrainConfig(
        out_dir=args.out,
        epochs=args.epochs,
        batch_size=args.batch_size,
        lr=args.lr,
        lr_schedule=args.lr_schedule,
        precision=precision,
        seed=args.seed,
        val_fraction=args.val_fraction,
        val_pairs=args.val_pairs,
        device=args.device,
        threads=args.threads,
        max_minutes=args.max_minutes,
        extra={"categories": args.categories},
    )
    init = model_class.from_file(args.init) if args.init else None
    history = fit(task, data.points, config, resume=args.resume, init_weights=init)
    if history:
        last = history[-1]
        print(
            f"trained {last['epoch']} epochs; best weights: {Path(args.out) / 'best.safetensors'}"
        )


def cmd_evaluate(args: argparse.Namespace) -> None:
    from masknet.data import load_modelnet40
    from masknet.evaluation.evaluate import evaluate_masknet, format_table
    from masknet.io import write_text_atomic

    model = _load_model(args)
    data = load_modelnet40(args.data, "test").subset(args.categories)
    result = evaluate_masknet(
        model,
        data.points,
        args.pairs,
        args.seed,
        _pair_config(args),
        precision=args.inference_precision,
        realign_rounds=args.realign_rounds,
    )
    print(
        f"{args.pairs} pairs from {len(data)} test shapes ({args.categories} categories), seed {args.seed}"
    )
    print(format_table(result.rows))
    print(f"top-k precision: standard error of the mean {result.topk_precision_stderr:.4f}")
    print(f"inference: {result.ms_per_pair:.2f} ms/pair (batched, {args.inference_precision})")
    if args.json:
        out = result.to_dict() | {
            "categories": args.categories,
            "weights": args.weights or args.pretrained,
        }
        write_text_atomic(args.json, json.dumps(out, indent=2) + "\n")
        print(f"wrote {args.json}")


def cmd_mask(args: argparse.Namespace) -> None:
    import numpy as np
    import torch

    from masknet.io import read_points, write_mask, write_points
    from masknet.models import select_mask

    template = read_points(args.template, drop_nonfinite=args.drop_nonfinite)
    source = read_points(args.source, drop_nonfinite=args.drop_nonfinite)
    model = _load_model(args)
    scores = model.predict(template, source, precision=args.inference_precision)
    k = None if args.threshold is not None else (args.k if args.k is not None else len(source))
    mask = select_mask(torch.from_numpy(scores[None]), k=k, threshold=args.threshold)[0].numpy()
    out = Path(args.output)
    mask_path = out.with_name(out.stem + "_mask.txt")
    _write_all(
        [
            (out, lambda p: write_points(p, template[mask])),
            (mask_path, lambda p: write_mask(p, mask)),
        ]
    )
    rule = (
        f"threshold {args.threshold}"
        if args.threshold is not None
        else f"top-k, k={min(k, len(template))}"
    )
    print(
        f"kept {int(mask.sum())} of {len(template)} template points ({rule}); "
        f"mean score {float(np.mean(scores)):.3f}"
    )
    print(f"wrote {out} and {mask_path}")
    if args.html:
        views = _write_views(
            args.html,
            {"template": template, "source": source, "inliers": template[mask]},
            title=f"MaskNet inliers: {Path(args.template).name} seen by {Path(args.source).name}",
        )
        print(f"wrote {views[0]} and {views[1]}")


def _write_all(writers: list[tuple[Path, Callable[[Path], None]]]) -> None:
    """Write every output or none: on a failure, remove those already written."""
    done: list[Path] = []
    try:
        for path, write in writers:
            write(path)
            done.append(path)
    except Exception:
        for path in done:
            path.unlink(missing_ok=True)
        raise


def cmd_register(args: argparse.Namespace) -> None:
    import numpy as np

    from masknet.io import read_points, write_points, write_text_atomic
    from masknet.registration import register

    if args.refine < 0:
        raise MaskNetError(f"--refine must be >= 0, got {args.refine}")
    template = read_points(args.template, drop_nonfinite=args.drop_nonfinite)
    source = read_points(args.source, drop_nonfinite=args.drop_nonfinite)
    model = None if args.no_mask else _load_model(args)
    options = {}
    if args.max_iterations is not None and args.method not in ("open3d-ransac", "open3d-fgr"):
        options["max_iterations"] = args.max_iterations
    if args.network_weights:
        from masknet.models import REGISTRATION_NETWORKS

        if args.method not in REGISTRATION_NETWORKS:
            raise MaskNetError(f"--network-weights needs a learned --method, not {args.method}")
        options["network"] = REGISTRATION_NETWORKS[args.method].from_file(args.network_weights)
    result = register(
        template,
        source,
        method=args.method,
        use_mask=not args.no_mask,
        iterations=args.iterations,
        model=model,
        precision=getattr(args, "inference_precision", "auto"),
        init=args.init,
        refine_iterations=args.refine,
        max_points=args.max_points,
        **options,
    )
    moved = source @ result.R.T + result.t
    out = Path(args.output)
    transform_path = out.with_name(out.stem + "_transform.txt")
    header = "source -> template: template ~= R @ source + t, [[R, t], [0, 0, 0, 1]]"
    text = header + "\n" + "\n".join(" ".join(f"{v:.10g}" for v in row) for row in result.transform)
    writers = [
        (out, lambda p: write_points(p, moved)),
        (transform_path, lambda p: write_text_atomic(p, text + "\n")),
    ]
    if result.mask is not None:
        inliers_path = out.with_name(out.stem + "_inliers" + out.suffix)
        writers.append((inliers_path, lambda p: write_points(p, template[result.mask])))
    _write_all(writers)

    pretty = {
        "icp": "ICP",
        "open3d-icp": "Open3D-ICP",
        "pointnetlk": "PointNetLK",
        "dcp": "DCP",
        "prnet": "PRNet",
        "pcrnet": "PCRNet",
        "rpmnet": "RPM-Net",
        "open3d-ransac": "Open3D-RANSAC",
        "open3d-fgr": "Open3D-FGR",
    }
    name = ("" if args.no_mask else "Mask-") + pretty[args.method]
    n, m = result.sampled
    sampled = "" if (n, m) == (len(template), len(source)) else f" (sampled to {n} and {m})"
    print(f"{name}: template {len(template)} points, source {len(source)}{sampled}")
    if result.mask is not None:
        print(f"inliers: {int(result.mask.sum())} of {len(template)} template points")
    angle = float(np.degrees(np.arccos(np.clip((np.trace(result.R) - 1) / 2, -1, 1))))
    print(
        f"rotation {angle:.2f} deg, translation {np.linalg.norm(result.t):.4g} "
        f"(input units); {1e3 * result.times['total']:.1f} ms"
    )
    print(
        "reported: " + ", ".join(f"{k} {np.asarray(v).item():.4g}" for k, v in result.info.items())
    )
    print(f"wrote {', '.join(str(p) for p, _ in writers)}")
    if args.html:
        layers = {"template": template, "source": source, "registered": moved}
        if result.mask is not None:
            layers["inliers"] = template[result.mask]
        views = _write_views(
            args.html,
            layers,
            title=f"{name}: {Path(args.source).name} -> {Path(args.template).name}",
        )
        print(f"wrote {views[0]} and {views[1]}")


def cmd_denoise(args: argparse.Namespace) -> None:
    from masknet.denoising import denoise
    from masknet.io import read_points, write_mask, write_points

    if not 0 <= args.threshold <= 1:
        raise MaskNetError(f"--threshold must be in [0, 1], got {args.threshold}")
    noisy = read_points(args.noisy, drop_nonfinite=args.drop_nonfinite)
    template = read_points(args.template, drop_nonfinite=args.drop_nonfinite)
    if args.method == "distance":
        result = denoise(noisy, template, method="distance", max_distance=args.max_distance)
        rule = f"distance <= {args.max_distance or '3x template spacing'}"
    else:
        model = _load_model(args)
        result = denoise(
            noisy,
            template,
            model=model,
            threshold=args.threshold,
            precision=args.inference_precision,
        )
        rule = f"MaskNet score >= {args.threshold}"
    out = Path(args.output)
    mask_path = out.with_name(out.stem + "_mask.txt")
    _write_all(
        [
            (out, lambda p: write_points(p, result.points)),
            (mask_path, lambda p: write_mask(p, result.mask)),
        ]
    )
    removed = int((~result.mask).sum())
    print(
        f"kept {int(result.mask.sum())} of {len(noisy)} points, removed {removed} "
        f"({100 * removed / len(noisy):.1f}%, {rule})"
    )
    print(f"wrote {out} and {mask_path}")
    if args.html:
        layers = {
            "template": template,
            "kept": result.points,
            "removed": noisy[~result.mask],
        }
        views = _write_views(args.html, layers, title=f"MaskNet denoising: {Path(args.noisy).name}")
        print(f"wrote {views[0]} and {views[1]}")


def cmd_show(args: argparse.Namespace) -> None:
    from masknet.io import read_points

    layers: dict = {}
    for file in args.clouds:
        name = Path(file).stem
        while name in layers:
            name += "'"
        layers[name] = read_points(file, drop_nonfinite=args.drop_nonfinite)
    title = args.title or ", ".join(Path(f).name for f in args.clouds)
    views = _write_views(args.output, layers, title)
    print(f"wrote {views[0]} and {views[1]}")


def cmd_benchmark(args: argparse.Namespace) -> None:
    import os
    import shlex

    import torch

    from masknet.data import bundled_sample_path
    from masknet.evaluation.benchmark import EXPERIMENTS, BenchmarkContext, run_experiments

    names = list(EXPERIMENTS) if args.experiment == "all" else [args.experiment]
    if names[0] not in EXPERIMENTS:
        raise MaskNetError(
            f"unknown experiment {args.experiment!r}; choose from {', '.join(EXPERIMENTS)} or all"
        )
    if args.threads:
        torch.set_num_threads(args.threads)
    data_path = args.data
    if args.quick and data_path is None and not os.environ.get("MASKNET_DATA"):
        data_path = bundled_sample_path()
    results = None
    if not args.quick and args.results != "none" and Path(args.results).exists():
        results = Path(args.results)
    argv = ["masknet", "benchmark", *sys.argv[2:]] if sys.argv[1:2] == ["benchmark"] else []
    ctx = BenchmarkContext(
        data=data_path,
        pairs=args.pairs or (20 if args.quick else 1000),
        seed=args.seed,
        quick=args.quick,
        out=Path(args.out),
        progress=sys.stderr.isatty(),
        command=shlex.join(argv) if argv else f"masknet benchmark {args.experiment}",
        resume=args.resume,
        log=None if sys.stderr.isatty() else functools.partial(print, file=sys.stderr, flush=True),
    )
    start = time.perf_counter()
    run_experiments(names, ctx, results, echo=functools.partial(print, flush=True))
    where = f" and {results}" if results else ""
    print(f"wrote {ctx.out}/{{{','.join(names)}}}.{{json,csv,png}}{where}")
    print(f"wall time {time.perf_counter() - start:.0f} s")


def cmd_demo(args: argparse.Namespace) -> None:
    import torch

    from masknet.data import bundled_sample_path, load_modelnet40
    from masknet.evaluation.evaluate import evaluate_masknet, format_table
    from masknet.io import write_text_atomic
    from masknet.models import select_mask
    from masknet.viz import plot_mask

    model = _load_model(args)
    sample = load_modelnet40(bundled_sample_path(), "test")
    result = evaluate_masknet(
        model,
        sample.points,
        args.pairs,
        args.seed,
        precision=args.inference_precision,
        progress=False,
        keep_outputs=True,
    )
    pairs = result.pairs_data
    print(
        f"MaskNet ({args.weights or args.pretrained}) on the bundled sample: {args.pairs} seeded pairs "
        f"from {len(sample)} ModelNet40 test shapes, 30% missing, rotation <= 45 deg, translation <= 1"
    )
    print(format_table(result.rows))
    print(f"inference: {result.ms_per_pair:.2f} ms/pair (batched, {args.inference_precision})")
    out = Path(args.out)
    predicted = select_mask(torch.from_numpy(result.scores[:1]), k=pairs.source.shape[1])[0].numpy()
    picture = plot_mask(
        pairs.template[0].numpy(),
        pairs.source[0].numpy(),
        predicted,
        out / "masknet_demo.png",
        truth=pairs.mask[0].numpy(),
        title="MaskNet: template inliers predicted from a partial source",
    )
    write_text_atomic(out / "metrics.json", json.dumps(result.to_dict(), indent=2) + "\n")
    print(f"wrote {picture} and {out / 'metrics.json'}")


def cmd_make_sample(args: argparse.Namespace) -> None:
    from masknet.data.sample import build_sample

    path = build_sample(args.data, args.output, args.per_class)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB)")


COMMANDS = {
    "train": cmd_train,
    "evaluate": cmd_evaluate,
    "mask": cmd_mask,
    "register": cmd_register,
    "benchmark": cmd_benchmark,
    "show": cmd_show,
    "denoise": cmd_denoise,
    "demo": cmd_demo,
    "make-sample": cmd_make_sample,
}


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        COMMANDS[args.command](args)
    except MaskNetError as exc:
        print(f"masknet: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("masknet: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. `masknet ... | head`: stop quietly, as Unix tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The ``masknet`` command: a thin layer over the Python API.

Every failure caused by input (missing file, bad format, NaN rows, wrong shape)
is printed as one line, ``masknet: error: <file>: <problem>``, with exit code 2.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
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
        "--keep-ratio", type=float, default=0.7, help="fraction of template points the source keeps"
    )
    g.add_argument("--max-angle", type=float, default=45.0, help="maximum rotation, degrees")
    g.add_argument("--max-translation", type=float, default=1.0, help="translation range per axis")
    g.add_argument(
        "--noise",
        type=float,
        default=0.0,
        help="Gaussian noise sigma on the source (clipped at 0.05)",
    )
    g.add_argument("--outliers", type=float, default=0.0, help="fraction of uniform outliers added")
    g.add_argument("--outlier-target", choices=["source", "template"], default="source")
    g.add_argument(
        "--categories",
        choices=["all", "seen", "unseen"],
        default="all",
        help="all 40, the first 20 (seen) or the last 20 (unseen) categories, alphabetical",
    )


def _pair_config(args: argparse.Namespace):
    from masknet.data import PairConfig

    try:
        return PairConfig(
            keep_ratio=args.keep_ratio,
            max_angle_deg=args.max_angle,
            max_translation=args.max_translation,
            noise_sigma=args.noise,
            outlier_ratio=args.outliers,
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

    p = sub.add_parser("train", help="train MaskNet on ModelNet40 (CPU or GPU), resumable")
    p.add_argument("--data", help="ModelNet40 folder or .npz (default: $MASKNET_DATA)")
    p.add_argument(
        "--out", required=True, help="run folder: checkpoint.pt, log.csv, best.safetensors"
    )
    p.add_argument("--epochs", type=_positive_int, default=100)
    p.add_argument("--batch-size", type=_positive_int, default=32)
    p.add_argument("--lr", type=float, default=1e-4)
    p.add_argument("--lr-schedule", choices=["constant", "cosine"], default="constant")
    p.add_argument("--loss", choices=["mse", "bce"], default="mse")
    p.add_argument(
        "--precision",
        choices=["auto", "fp32", "bf16"],
        default="auto",
        help="autocast dtype; auto = bf16 where the hardware has it",
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
    p.add_argument(
        "--drop-nonfinite", action="store_true", help="drop NaN/inf rows instead of failing"
    )
    _add_model_options(p)

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


def _add_model_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("model")
    g.add_argument(
        "--weights", help="a .safetensors file from masknet train (default: shipped weights)"
    )
    g.add_argument(
        "--pretrained", default="modelnet40", help="name of shipped weights (default modelnet40)"
    )
    g.add_argument("--inference-precision", choices=["fp32", "bf16"], default="fp32")


def _load_model(args: argparse.Namespace):
    from masknet.models import MaskNet

    return MaskNet.from_file(args.weights) if args.weights else MaskNet.pretrained(args.pretrained)


def cmd_train(args: argparse.Namespace) -> None:
    from masknet.data import load_modelnet40
    from masknet.models import MaskNet
    from masknet.training import MaskNetTask, TrainConfig, fit

    data = load_modelnet40(args.data, "train").subset(args.categories)
    if not 16 <= args.num_points <= data.points.shape[1]:
        raise MaskNetError(
            f"--num-points must be in [16, {data.points.shape[1]}], got {args.num_points}"
        )
    task = MaskNetTask(pairs=_pair_config(args), num_points=args.num_points, loss=args.loss)
    config = TrainConfig(
        out_dir=args.out,
        epochs=args.epochs,
        batch_size=args.batch_size,
        lr=args.lr,
        lr_schedule=args.lr_schedule,
        precision=args.precision,
        seed=args.seed,
        val_fraction=args.val_fraction,
        val_pairs=args.val_pairs,
        device=args.device,
        threads=args.threads,
        max_minutes=args.max_minutes,
        extra={"categories": args.categories},
    )
    init = MaskNet.from_file(args.init) if args.init else None
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
    )
    print(
        f"{args.pairs} pairs from {len(data)} test shapes ({args.categories} categories), seed {args.seed}"
    )
    print(format_table(result.rows))
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
    write_points(out, template[mask])
    try:
        write_mask(mask_path, mask)
    except Exception:
        out.unlink(missing_ok=True)  # never leave one output without the other
        raise
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
    return 0


if __name__ == "__main__":
    sys.exit(main())

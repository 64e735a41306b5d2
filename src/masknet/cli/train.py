"""``masknet train``: MaskNet, the denoiser or a registration network on ModelNet40."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

from masknet.cli import _scans
from masknet.cli._common import (
    add_output_option,
    add_pair_options,
    json_object,
    pair_config,
    positive_int,
    seed,
)
from masknet.cli._outputs import refuse_inputs
from masknet.errors import MaskNetError
from masknet.registration.terms.methods import NETWORK_METHODS

if TYPE_CHECKING:
    from masknet.training import Task


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``train`` to the ``masknet`` subparsers."""
    p = subparsers.add_parser(
        "train",
        help="train MaskNet or a registration network (resumable)",
        description="train MaskNet or a registration network on ModelNet40 (CPU or GPU), resumable",
    )
    p.add_argument(
        "--model",
        choices=list(MODELS),
        default="masknet",
        help="masknet (partial pairs), crossmasknet (a stronger template mask: local "
        "geometry and attention between the clouds; --loss bce suits it), masknet2 (the two-sided MaskNet: template and "
        "source masks, trained with outliers and clutter in the source; --init names the "
        "MaskNet it starts from, default modelnet40), refine (the refinement mask of rounds >= 2: "
        "both masks of a pair already brought close, trained with residual poses, outliers and "
        "clutter; --init fine-tunes a refinement-mask file), denoise (MaskNet scoring the points of a source "
        "with outliers, 10%% by default), or a registration network: pointnetlk, dcp, "
        "pcrnet (full-cloud pairs, as their papers train) or prnet, rpmnet (partial pairs)",
    )
    p.add_argument("--data", help="ModelNet40 folder or .npz (default: $MASKNET_DATA)")
    add_output_option(
        p,
        old="--out",
        required=True,
        metavar="OUTDIR",
        help="run folder: best.safetensors (the weights to use), last.safetensors, "
        "checkpoint.safetensors (for --resume), log.csv, run.json",
    )
    p.add_argument("--epochs", type=positive_int, default=100, help="epochs (default 100)")
    p.add_argument(
        "--batch-size", type=positive_int, default=32, help="pairs per step (default 32)"
    )
    p.add_argument("--lr", type=float, default=1e-4, help="Adam learning rate (default 1e-4)")
    p.add_argument(
        "--lr-schedule",
        choices=["constant", "cosine"],
        default="constant",
        help="constant (default) or cosine decay over the epochs",
    )
    p.add_argument("--loss", choices=["mse", "bce"], default="mse", help="masknet only")
    _add_network_options(p)
    _add_pair_count_options(p)
    _add_run_options(p)
    _add_start_options(p)
    add_pair_options(p)
    _scans.add_train_options(p)


def _add_network_options(p: argparse.ArgumentParser) -> None:
    """``--feature-size``, ``--iterations``, ``--model-config`` and ``--precision``: the
    network's shape and number format."""
    p.add_argument(
        "--feature-size",
        type=positive_int,
        help="PointNet feature size K (last encoder width); default 1024",
    )
    p.add_argument(
        "--iterations",
        "--lk-iterations",
        dest="iterations",
        type=positive_int,
        help="registration networks: refinement iterations per training pair (default: "
        "pointnetlk 10, dcp 1, pcrnet 3, prnet 2, rpmnet 2)",
    )
    p.add_argument(
        "--model-config",
        type=json_object,
        default=None,
        metavar="JSON",
        help="keyword arguments of the network class, e.g. "
        '\'{"embedding": 128, "k": 16}\' for dcp, \'{"context": 16}\' for masknet (a '
        "residual context head over 16 template neighbours and the source's points), "
        '\'{"descriptors": "fpfh"}\' for crossmasknet (FPFH descriptor inputs beside the '
        "coordinates; needs Open3D); default: the paper's sizes",
    )
    p.add_argument(
        "--precision",
        choices=["auto", "fp32", "bf16"],
        default="auto",
        help="autocast dtype; auto = bf16 where the hardware has it (masknet only: the "
        "registration networks train in fp32)",
    )


def _add_pair_count_options(p: argparse.ArgumentParser) -> None:
    """``--num-points``, ``--val-fraction``, ``--val-pairs`` and ``--seed``: how many points,
    shapes and pairs, drawn how."""
    p.add_argument(
        "--num-points", type=positive_int, default=1024, help="template points per training pair"
    )
    p.add_argument(
        "--val-fraction", type=float, default=0.1, help="training shapes held out for validation"
    )
    p.add_argument(
        "--val-pairs",
        type=positive_int,
        default=512,
        help="validation pairs made from those shapes",
    )
    p.add_argument("--seed", type=seed, default=0, help="seed of pairs and weights (default 0)")


def _add_run_options(p: argparse.ArgumentParser) -> None:
    """``--device``, ``--threads``, the time limits and ``--resume``: where and how long
    the run goes."""
    p.add_argument(
        "--device", default="auto", help="auto (default: a GPU if there is one), cpu, cuda, ..."
    )
    p.add_argument("--threads", type=positive_int, help="torch CPU threads")
    p.add_argument(
        "--max-minutes",
        type=float,
        help="minutes for this invocation: no epoch starts that would end past it",
    )
    p.add_argument(
        "--checkpoint-minutes",
        type=float,
        help="also checkpoint within an epoch this often (SIGTERM always saves where the "
        "run stands and exits; --resume goes on from there)",
    )
    p.add_argument("--resume", action="store_true", help="continue the checkpoint in OUTDIR")


def _add_start_options(p: argparse.ArgumentParser) -> None:
    """``--init``, ``--template-mask`` and ``--distill``: the weights a run starts from or
    learns beside."""
    p.add_argument(
        "--init",
        help="start from these weights, e.g. to fine-tune: a .safetensors file or the name "
        "of shipped weights (modelnet40, scans, ...)",
    )
    p.add_argument(
        "--template-mask",
        metavar="MASKNET",
        help="registration networks: train Mask-X, on the template points this MaskNet keeps "
        "(shipped name, e.g. modelnet40, or a .safetensors file) against the partial source; "
        "pair with --keep-ratio 0.7",
    )
    p.add_argument(
        "--distill",
        metavar="MASKNET",
        help="masknet: learn from this frozen MaskNet's scores as well as the labels (shipped "
        "name, e.g. modelnet40, or a .safetensors file); with --loss bce and a smaller "
        "--model-config",
    )
    p.add_argument(
        "--distill-weight",
        type=float,
        default=0.5,
        help="the teacher's share of the target with --distill, in [0, 1] (default 0.5)",
    )


class TrainSetup(NamedTuple):
    """What :func:`build_task` makes of the options."""

    task: Task
    model_class: type  # reads --init weights (``from_file``)
    precision: str  # the autocast precision: "auto", "fp32" or "bf16"


def build_task(args: argparse.Namespace) -> TrainSetup:
    """The training task of ``--model`` (and the pair options), its model class and the
    precision to train in: the builder of :data:`TASK_BUILDERS` for that model.

    Raises:
        MaskNetError: ``--model-config`` does not fit the network, bf16 for a
            registration network, or an option the model does not take.
    """
    if args.template_mask and args.model not in NETWORK_METHODS:
        raise MaskNetError(
            f"--template-mask trains a registration network, not --model {args.model}"
        )
    if args.distill and args.model not in ("masknet", "crossmasknet"):
        raise MaskNetError(f"--distill trains a MaskNet (--model masknet), not {args.model}")
    if args.scans and args.model in NETWORK_METHODS:
        raise MaskNetError(f"--scans trains MaskNet (--model masknet), not {args.model}")
    return TASK_BUILDERS[args.model](args)


def _encoder(args: argparse.Namespace) -> dict:
    """``--feature-size`` as the encoder's widths (the paper's but the last)."""
    return {"encoder_channels": [64, 64, 64, 128, args.feature_size]} if args.feature_size else {}


def _masknet(args: argparse.Namespace) -> TrainSetup:
    from masknet.training import MaskNetTask
    from masknet.training.masknet_task import MASK_NETWORKS

    MaskNet = MASK_NETWORKS[args.model]  # noqa: N806 (the network class of --model)
    if args.model != "masknet" and args.feature_size:
        raise MaskNetError(
            f"--feature-size is MaskNet's; set {args.model}'s sizes with --model-config"
        )
    settings = {
        "network": args.model,
        "pairs": pair_config(args),
        "num_points": args.num_points,
        "loss": args.loss,
        "model_config": _encoder(args) | (args.model_config or {}),
    }
    if args.distill:
        settings |= {"teacher": args.distill, "distill_weight": args.distill_weight}
    try:
        MaskNetTask(**settings).build_model()
    except (TypeError, ValueError) as exc:
        raise MaskNetError(f"masknet: {exc}") from None
    if args.scans:
        return TrainSetup(
            MaskNetTask.on_scans(_scans.scan_mix(args), **settings), MaskNet, args.precision
        )
    return TrainSetup(MaskNetTask(**settings), MaskNet, args.precision)


def _denoise(args: argparse.Namespace) -> TrainSetup:
    from masknet.models import MaskNet
    from masknet.training import MaskNetTask

    task = MaskNetTask.denoising(
        pair_config(args, default_outliers=0.1),
        num_points=args.num_points,
        loss=args.loss,
        model_config=_encoder(args),
    )
    return TrainSetup(task, MaskNet, args.precision)


def _two_sided(args: argparse.Namespace) -> TrainSetup:
    from masknet.models.two_sided import TwoSidedMaskNet
    from masknet.training.two_sided_task import TwoSidedTask

    settings = {"pairs": pair_config(args), "num_points": args.num_points}
    if args.init:
        settings["init"] = args.init
        args.init = None  # the task starts from those MaskNet weights itself
    if args.scans:
        settings["mix"] = _scans.scan_mix(args)
    return TrainSetup(TwoSidedTask(**settings), TwoSidedMaskNet, args.precision)


def _refine(args: argparse.Namespace) -> TrainSetup:
    from masknet.models.refine import RefineMaskNet
    from masknet.training.refine_task import RefineMaskTask

    settings = {
        "pairs": pair_config(args),
        "num_points": args.num_points,
        "model_config": args.model_config if args.model_config is not None else {},
    }
    if args.init:
        settings["init"] = args.init
        args.init = None  # the task loads those weights itself
    if args.scans:
        settings["mix"] = _scans.scan_mix(args, modelnet_view_fraction=0.5)
    task = RefineMaskTask(**settings)
    try:
        task.build_model()
    except (TypeError, MaskNetError) as exc:
        raise MaskNetError(f"refine: {exc}") from None
    return TrainSetup(task, RefineMaskNet, args.precision)


def _registration_network(args: argparse.Namespace) -> TrainSetup:
    from masknet.models import REGISTRATION_NETWORKS
    from masknet.training import TRAINING_DEFAULTS, RegistrationTask

    if args.template_mask:
        from masknet.training.registration_task import load_mask_network

        load_mask_network(args.template_mask)  # a wrong name fails before the data loads
    defaults = TRAINING_DEFAULTS[args.model]
    task = RegistrationTask(
        pairs=pair_config(args, default_keep_ratio=defaults["keep_ratio"]),
        num_points=args.num_points,
        name=args.model,
        iterations=args.iterations or defaults["iterations"],
        model_config=args.model_config if args.model_config is not None else _encoder(args),
        template_mask=args.template_mask,
    )
    try:
        task.build_model()
    except TypeError as exc:
        raise MaskNetError(f"--model-config does not fit {args.model}: {exc}") from None
    if args.precision == "bf16":
        raise MaskNetError(
            f"--precision bf16 does not suit {args.model}: registration networks train "
            "in fp32 (PointNetLK's finite-difference Jacobian and the SVDs need it)"
        )
    return TrainSetup(task, REGISTRATION_NETWORKS[args.model], "fp32")


# --model -> the builder of its task, as the method table maps a method to its adapter.
TASK_BUILDERS = {
    "masknet": _masknet,
    "crossmasknet": _masknet,
    "masknet2": _two_sided,
    "refine": _refine,
    "denoise": _denoise,
    **dict.fromkeys(NETWORK_METHODS, _registration_network),
}
MODELS = tuple(TASK_BUILDERS)


def run(args: argparse.Namespace) -> None:
    """Train; prints where the best weights went."""
    from masknet.training import TrainConfig, fit
    from masknet.training.loop import CHECKPOINT, RUN_OUTPUTS

    # --init best.safetensors of the same folder would be overwritten by the first epoch.
    run_files = [Path(args.output) / name for name in (*RUN_OUTPUTS, CHECKPOINT)]
    given = (args.init, args.template_mask, args.distill, args.data)
    refuse_inputs(run_files, filter(None, given), hint="give the run another folder")
    task, model_class, precision = build_task(args)
    points = _training_shapes(args)
    if len(points) and not 16 <= args.num_points <= points.shape[1]:
        raise MaskNetError(
            f"--num-points must be in [16, {points.shape[1]}], got {args.num_points}"
        )
    config = TrainConfig(
        out_dir=args.output,
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
        checkpoint_minutes=args.checkpoint_minutes,
        extra={"categories": args.categories},
    )
    init = _init_weights(model_class, args.init) if args.init else None
    if init is not None and not getattr(task, "model_config", True):
        # Fine-tuning keeps the architecture of the weights it starts from.
        task.model_config = dict(init.config)
    try:
        history = fit(task, points, config, resume=args.resume, init_weights=init)
    except KeyboardInterrupt:
        from masknet.training.loop import CHECKPOINT

        if (Path(args.output) / CHECKPOINT).exists():
            raise KeyboardInterrupt(
                f"the last finished epoch is saved in {Path(args.output) / CHECKPOINT}; "
                "run the same command with --resume to continue"
            ) from None
        raise KeyboardInterrupt("before the first epoch finished: nothing was saved") from None
    if history:
        epochs = history[-1]["epoch"]
        best = Path(args.output) / "best.safetensors"
        print(f"trained {epochs} epoch{'s' if epochs != 1 else ''}; best weights: {best}")
        if epochs < args.epochs:
            print(f"{args.epochs - epochs} epochs left: the same command with --resume continues")
        else:
            print(
                "use them: "
                + _USE[args.model if args.model in _USE else "network"].format(
                    best=best, model=args.model
                )
            )


# How a finished run's best weights are used, per --model.
_USE = {
    "masknet": "masknet evaluate, mask and register take --weights {best}",
    "crossmasknet": "in Python, CrossMaskNet.from_file('{best}'); any Mask-X takes it as "
    "register(..., model=...)",
    "masknet2": "masknet register --two-sided and masknet denoise --method masknet take "
    "--weights {best}",
    "denoise": "masknet denoise --method masknet takes --weights {best}",
    "refine": "in Python, register(template, source, iterations=3, "
    "refine_masks=RefineMaskNet.from_file('{best}'))",
    "network": "masknet register --method {model} --weights {best}",
}


def _training_shapes(args: argparse.Namespace):
    """ModelNet40's training shapes (S, N, 3), or none (S = 0) when scans train alone:
    ``--modelnet-fraction 0``, or ``--scans`` with no ModelNet40 data given."""
    import os

    import numpy as np

    from masknet.data import load_modelnet40

    if args.scans and (
        args.modelnet_fraction == 0 or not (args.data or os.environ.get("MASKNET_DATA"))
    ):
        print("training on the scans alone (no ModelNet40 shapes)")
        return np.zeros((0, args.num_points, 3), np.float32)
    return load_modelnet40(args.data, "train").subset(args.categories).points


def _init_weights(model_class: type, name: str):
    """``--init``: a weights file, or the name of shipped weights of that class."""
    if Path(name).suffix == ".safetensors" or Path(name).exists():
        return model_class.from_file(name)
    return model_class.pretrained(name)

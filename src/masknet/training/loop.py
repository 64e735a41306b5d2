"""One training loop for every model.

A model plugs in through a :class:`Task` (how to build the model, make batches,
compute the loss and export weights). The loop owns the rest:

* Adam, optional cosine learning-rate decay, fp32 or bf16 autocast;
* validation on a split held out of the *training* shapes (never the test set);
* a progress bar with loss and the task's metric (tqdm, the ``train`` extra);
* an atomic checkpoint every epoch (``checkpoint.safetensors``, nothing pickled,
  :mod:`masknet.training.checkpoint`; written to a temporary
  file then renamed), so a kill at any moment loses at most the current epoch,
  and ``resume=True`` continues where it stopped;
* a CSV log (``log.csv``) and the best weights by validation metric
  (``best.safetensors``, via the task's exporter);
* several processes under ``torchrun`` (DistributedDataParallel; gloo on CPU,
  NCCL on GPUs): ``batch_size`` stays the *global* batch, each of the W processes
  takes its 1/W slice of every batch, and the averaged gradients equal
  single-process training on the same pairs (exactly so for models without
  BatchNorm; with BatchNorm each process normalises over its own slice, except on
  GPUs where SyncBatchNorm is used). Rank 0 validates, logs and writes files.

Pairs are a pure function of (seed, epoch, batch), so a resumed run sees the
same data it would have seen without the interruption.
"""

from __future__ import annotations

import csv
import json
import math
import os
import sys
import time
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np
import torch
from torch import Tensor, nn

from masknet._atomic import atomic_target
from masknet._extras import progress_bar
from masknet.errors import MaskNetError
from masknet.runtime import default_precision, resolve_device
from masknet.training.checkpoint import load_checkpoint, save_checkpoint

__all__ = ["Task", "TrainConfig", "fit", "split_train_val"]


class Task(Protocol):
    """What the loop needs to know about one model family."""

    name: str
    metric: str  # validation metric that picks best.safetensors, a key of step()'s metrics
    maximize: bool  # True: higher metric is better (precision); False: lower (an error)

    def build_model(self) -> nn.Module: ...

    def train_batches(
        self, points: np.ndarray, batch_size: int, seed: int, epoch: int
    ) -> Iterable[Any]: ...

    def val_batches(
        self, points: np.ndarray, num_pairs: int, batch_size: int, seed: int
    ) -> list[Any]: ...

    def step(
        self, model: nn.Module, batch: Any, device: torch.device
    ) -> tuple[Tensor, dict[str, float]]: ...

    def export(self, model: nn.Module, path: Path, metadata: dict) -> None: ...

    def describe(self) -> dict: ...


@dataclass
class TrainConfig:
    """Optimisation settings. Defaults follow the paper: Adam, lr 1e-4, batch 32."""

    out_dir: str
    epochs: int = 100
    batch_size: int = 32
    lr: float = 1e-4
    lr_schedule: Literal["constant", "cosine"] = "constant"
    min_lr: float = 1e-6
    precision: Literal["auto", "fp32", "bf16"] = "auto"
    seed: int = 0
    val_fraction: float = 0.1
    val_pairs: int = 512
    device: str = "auto"
    threads: int | None = None
    max_minutes: float | None = None  # per invocation: no epoch starts that would end past it
    extra: dict = field(default_factory=dict)


# Settings that may change between a run and its --resume; any other change is refused,
# because it would change the data split, the pairs or the model being continued.
RESUMABLE_CHANGES = {"epochs", "max_minutes", "threads", "device"}


def _check_config(config: TrainConfig, n_train: int) -> None:
    if n_train < config.batch_size:
        raise MaskNetError(
            f"{n_train} training shapes are fewer than one batch of {config.batch_size}; "
            "lower --batch-size or --val-fraction"
        )


def _check_resumable(path: Path, saved: dict | None, current: dict) -> None:
    if saved is None:
        return  # checkpoints from before run_info was stored
    # Compare as stored: JSON turns tuples into lists.
    saved, current = (json.loads(json.dumps(x, default=list)) for x in (saved, current))
    changed = [
        key
        for key in sorted(set(saved["train"]) | set(current["train"]))
        if key not in RESUMABLE_CHANGES and saved["train"].get(key) != current["train"].get(key)
    ]
    if saved["task"] != current["task"]:
        changed.append("task/pair settings")
    if changed:
        raise MaskNetError(
            f"{path}: cannot resume with different settings ({', '.join(changed)}); "
            "use the original ones or a new --output"
        )


def split_train_val(
    num_shapes: int, val_fraction: float, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Seeded split of training-shape indices into (train, validation)."""
    order = np.random.default_rng(seed).permutation(num_shapes)
    n_val = max(1, round(val_fraction * num_shapes)) if val_fraction > 0 else 0
    return np.sort(order[n_val:]), np.sort(order[:n_val])


CHECKPOINT = "checkpoint.safetensors"
# What a run writes beside its checkpoint once an epoch has finished.
RUN_OUTPUTS = ("best.safetensors", "last.safetensors", "log.csv")


def _checkpoint_path(out: Path) -> Path:
    """The run's checkpoint: ``checkpoint.safetensors``, or an earlier version's ``.pt``."""
    legacy = out / "checkpoint.pt"
    return legacy if legacy.exists() and not (out / CHECKPOINT).exists() else out / CHECKPOINT


def _write_csv(rows: list[dict], path: Path) -> None:
    with atomic_target(path) as tmp, open(tmp, "w", newline="") as fh:
        # Every key of every row, in first-seen order: a mixed task's kinds vary by epoch.
        writer = csv.DictWriter(fh, fieldnames=list(dict.fromkeys(k for r in rows for k in r)))
        writer.writeheader()
        writer.writerows(rows)


def _learning_rate(config: TrainConfig, epoch: int) -> float:
    if config.lr_schedule == "constant":
        return config.lr
    progress = epoch / max(1, config.epochs - 1)
    return config.min_lr + 0.5 * (config.lr - config.min_lr) * (1 + math.cos(math.pi * progress))


def fit(
    task: Task,
    train_points: np.ndarray,
    config: TrainConfig,
    resume: bool = False,
    init_weights: nn.Module | None = None,
) -> list[dict]:
    """Train ``task``'s model on shapes (S, N, 3); returns the per-epoch log rows.

    ``train_points`` is split by :func:`split_train_val` into training and
    validation shapes; it may hold no shapes (S = 0) for a task that brings its own
    data, such as a MaskNet task on scans alone (:meth:`~masknet.training.masknet_task.MaskNetTask.on_scans`). ``init_weights`` optionally starts from another model's
    weights (fine-tuning); it is ignored when resuming. Under torchrun only rank 0
    returns the log rows (the others return an empty list).
    """
    if config.batch_size < 1 or config.epochs < 1:
        raise MaskNetError("--batch-size and --epochs must be at least 1")
    if not 0 <= config.val_fraction < 1:
        raise MaskNetError(f"--val-fraction must be in [0, 1), got {config.val_fraction}")
    train_idx, val_idx = split_train_val(len(train_points), config.val_fraction, config.seed)
    if len(train_points):  # no shapes at all: the task brings its own data (e.g. scans)
        _check_config(config, len(train_idx))
    out = Path(config.out_dir)
    if out.exists() and not out.is_dir():
        raise MaskNetError(f"{out}: exists and is not a folder; choose another --output")
    ckpt_path = _checkpoint_path(out)
    if ckpt_path.exists() and not resume:
        raise MaskNetError(
            f"{ckpt_path} exists: pass --resume to continue it, or choose another --output"
        )
    if not ckpt_path.exists():
        # An earlier run's results without its checkpoint cannot be continued, and a new
        # run would overwrite them.
        earlier = [name for name in RUN_OUTPUTS if (out / name).exists()]
        if earlier:
            raise MaskNetError(
                f"{out} holds an earlier run ({', '.join(earlier)}) but no checkpoint to "
                "continue; choose another --output, or move those files away"
            )
    device = resolve_device(config.device)
    rank, world, joined = _init_distributed(device)
    if not joined:
        return _fit(task, train_points, config, resume, init_weights, device, rank, world)
    # Leave the group before the interpreter exits: gloo threads still running at exit
    # abort the process ("terminate called without an active exception").
    import torch.distributed as dist

    try:
        history = _fit(task, train_points, config, resume, init_weights, device, rank, world)
        dist.barrier()  # no rank tears down while another still writes or syncs
        return history
    finally:
        dist.destroy_process_group()


def _fit(
    task: Task,
    train_points: np.ndarray,
    config: TrainConfig,
    resume: bool,
    init_weights: nn.Module | None,
    device: torch.device,
    rank: int,
    world: int,
) -> list[dict]:
    """fit() once the process group, if any, is joined."""
    train_idx, val_idx = split_train_val(len(train_points), config.val_fraction, config.seed)
    out = Path(config.out_dir)
    ckpt_path = _checkpoint_path(out)
    if world > 1 and device.type == "cuda":
        device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
    if config.batch_size % world:
        raise MaskNetError(
            f"--batch-size {config.batch_size} must be divisible by the {world} processes"
        )
    lead = rank == 0
    precision = default_precision(device) if config.precision == "auto" else config.precision
    if config.threads:
        torch.set_num_threads(config.threads)

    run_info = {
        "task": task.describe(),
        "train": {k: v for k, v in asdict(config).items() if k != "out_dir"}
        | {"precision": precision},
        "shapes": {"train": len(train_idx), "val": len(val_idx)},
    }

    torch.manual_seed(config.seed)
    model = task.build_model().to(device)
    if init_weights is not None:
        _load_init(model, init_weights)
    train_model: nn.Module = model
    if world > 1:
        if device.type == "cuda":
            model = nn.SyncBatchNorm.convert_sync_batchnorm(model)
        train_model = nn.parallel.DistributedDataParallel(model)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    history: list[dict] = []
    best = -math.inf
    start_epoch = 0
    if resume and ckpt_path.exists():
        state = load_checkpoint(ckpt_path, model, optimizer, device)
        _check_resumable(ckpt_path, state.get("run_info"), run_info)
        history, best, start_epoch = state["history"], state["best"], state["epoch"]
        if lead and start_epoch >= config.epochs:
            print(
                f"{ckpt_path}: already finished {start_epoch} of {config.epochs} epochs; "
                "raise --epochs to train more",
                file=sys.stderr,
            )
        elif lead:
            print(f"resuming {ckpt_path} at epoch {start_epoch + 1}", file=sys.stderr)
    elif resume and lead:
        print(f"no checkpoint in {out}: starting a fresh run", file=sys.stderr)

    train_set = train_points[train_idx]
    val_batches = (
        task.val_batches(train_points[val_idx], config.val_pairs, config.batch_size, config.seed)
        if len(val_idx) or (config.val_fraction > 0 and not len(train_points))
        else []
    )
    if lead:
        out.mkdir(parents=True, exist_ok=True)
        (out / "run.json").write_text(json.dumps(run_info, indent=2))
    autocast = torch.autocast(device.type, dtype=torch.bfloat16, enabled=precision == "bf16")
    interactive = sys.stderr.isatty()
    started = time.perf_counter()
    elapsed_before = history[-1]["elapsed_min"] if history else 0.0

    for epoch in range(start_epoch, config.epochs):
        lr = _learning_rate(config, epoch)
        for group in optimizer.param_groups:
            group["lr"] = lr
        train_model.train()
        epoch_start = time.perf_counter()
        sums: dict[str, float] = {}
        counts: dict[str, int] = {}  # per key: a mixed task's metrics need not be in every batch
        count = 0
        batches = task.train_batches(train_set, config.batch_size, config.seed, epoch)
        total = len(batches) if hasattr(batches, "__len__") else len(train_set) // config.batch_size
        bar = progress_bar(
            batches,
            total=total,
            desc=f"epoch {epoch + 1}/{config.epochs}",
            leave=interactive,
            mininterval=0.5 if interactive else 60,
            file=sys.stderr,
            disable=not lead,
        )
        for batch in bar:
            if world > 1:
                batch = type(batch)(*(x.tensor_split(world)[rank] for x in batch))
            with autocast:
                loss, metrics = task.step(train_model, batch, device)
            loss_value = loss.item()
            if not math.isfinite(loss_value):
                raise MaskNetError(f"training diverged at epoch {epoch + 1}: loss is {loss_value}")
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            count += 1
            for key, value in {"loss": loss_value, **metrics}.items():
                sums[key] = sums.get(key, 0.0) + value
                counts[key] = counts.get(key, 0) + 1
            shown = {k: f"{sums[k] / counts[k]:.3f}" for k in (task.metric,) if k in sums}
            bar.set_postfix(loss=f"{sums['loss'] / count:.4f}", **shown, refresh=False)
        bar.close()
        means = {k: v / counts[k] for k, v in sums.items()}
        if world > 1:
            means = _mean_over_processes(means, device)
        row = {"epoch": epoch + 1, "lr": lr}
        row.update({f"train_{k}": v for k, v in means.items()})
        stop = False
        if lead:
            row.update(
                {
                    f"val_{k}": v
                    for k, v in _validate(task, model, val_batches, device, autocast).items()
                }
            )
            row["epoch_min"] = (time.perf_counter() - epoch_start) / 60
            row["elapsed_min"] = elapsed_before + (time.perf_counter() - started) / 60
            history.append(row)

            score = row[f"val_{task.metric}"] if val_batches else row[f"train_{task.metric}"]
            score = score if task.maximize else -score
            meta = {"epoch": epoch + 1, **run_info, "val": row}
            if score > best:
                best = score
                task.export(model, out / "best.safetensors", meta)
            task.export(model, out / "last.safetensors", meta)
            save_checkpoint(
                out / CHECKPOINT,
                model,
                optimizer,
                {
                    "epoch": epoch + 1,
                    "history": history,
                    "best": best,
                    "run_info": run_info,
                },
            )
            _write_csv(history, out / "log.csv")
            print(
                f"epoch {epoch + 1}: "
                + ", ".join(
                    f"{k} {v:.3g}" if k == "lr" else f"{k} {v:.4f}"  # lr exact: 5e-05, not 0.0001
                    for k, v in row.items()
                    if k != "epoch"
                ),
                file=sys.stderr,
                flush=True,
            )
            if config.max_minutes is not None:
                spent = (time.perf_counter() - started) / 60
                if spent + row["epoch_min"] > config.max_minutes:
                    print(
                        f"stopping: time budget of {config.max_minutes} min reached",
                        file=sys.stderr,
                    )
                    stop = True
        if world > 1:
            stop = _broadcast_flag(stop, device)
        if stop:
            break
    return history


def _load_init(model: nn.Module, init_weights: nn.Module) -> None:
    """Start ``model`` from ``init_weights``: every tensor must fit, and only an added
    residual head (``context.*``, which starts at zero) may be missing from them."""
    try:
        missing, unexpected = model.load_state_dict(init_weights.state_dict(), strict=False)
    except RuntimeError as exc:
        raise MaskNetError(f"--init weights do not fit this model ({exc})") from None
    missing = [k for k in missing if not k.startswith("context.")]
    if missing or unexpected:
        raise MaskNetError(
            f"--init weights do not fit this model (missing {missing[:3]}, "
            f"unexpected {unexpected[:3]})"
        )


def _init_distributed(device: torch.device) -> tuple[int, int, bool]:
    """(rank, world size, joined): joins the process group when started by torchrun;
    ``joined`` says that this call did, so that fit() leaves it again."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world == 1:
        return 0, 1, False
    import torch.distributed as dist

    joined = not dist.is_initialized()
    if joined:
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
    return dist.get_rank(), dist.get_world_size(), joined


def _mean_over_processes(sums: dict[str, float], device: torch.device) -> dict[str, float]:
    """Average per-process metric means, so rank 0 logs the whole batch."""
    import torch.distributed as dist

    keys = sorted(sums)
    on = device if device.type == "cuda" else "cpu"
    values = torch.tensor([sums[k] for k in keys], dtype=torch.float64, device=on)
    dist.all_reduce(values)
    return {k: float(v) / dist.get_world_size() for k, v in zip(keys, values, strict=True)}


def _broadcast_flag(flag: bool, device: torch.device) -> bool:
    """Rank 0's decision, on every rank (so all stop at the same epoch)."""
    import torch.distributed as dist

    value = torch.tensor([int(flag)], device=device if device.type == "cuda" else "cpu")
    dist.broadcast(value, src=0)
    return bool(value.item())


@torch.no_grad()
def _validate(
    task: Task, model: nn.Module, batches: list, device: torch.device, autocast
) -> dict[str, float]:
    if not batches:
        return {}
    model.eval()
    sums: dict[str, float] = {}
    counts: dict[str, int] = {}
    for batch in batches:
        with autocast:
            loss, metrics = task.step(model, batch, device)
        for key, value in {"loss": loss.item(), **metrics}.items():
            sums[key] = sums.get(key, 0.0) + value
            counts[key] = counts.get(key, 0) + 1
    return {k: v / counts[k] for k, v in sums.items()}

"""One training loop for every model.

A model plugs in through a :class:`Task` (how to build the model, make batches,
compute the loss and export weights). The loop owns the rest:

* Adam, optional cosine learning-rate decay, fp32 or bf16 autocast;
* validation on a split held out of the *training* shapes (never the test set);
* a progress bar with loss and the task's metric (tqdm, the ``train`` extra);
* an atomic checkpoint every epoch (``checkpoint.safetensors``, nothing pickled,
  :mod:`masknet.training.checkpoint`; written to a temporary
  file then renamed), so a kill at any moment loses at most the current epoch,
  and ``resume=True`` continues where it stopped; with ``checkpoint_minutes`` also
  within an epoch, every that many minutes, and always on SIGTERM (the run saves where
  it stands and exits), so a long run can stop and go on elsewhere losing nothing;
* a CSV log (``log.csv``) and the best weights by validation metric
  (``best.safetensors``, via the task's exporter);
* several processes under ``torchrun`` (DistributedDataParallel; gloo on CPU,
  NCCL on GPUs): ``batch_size`` stays the *global* batch, each of the W processes
  takes its 1/W slice of every batch, and the averaged gradients equal
  single-process training on the same pairs (exactly so for models without
  BatchNorm; with BatchNorm each process normalises over its own slice, except on
  GPUs where SyncBatchNorm is used). Rank 0 validates, logs and writes files.

Pairs are a pure function of (seed, epoch, batch), so a resumed run sees the
same data it would have seen without the interruption: a run resumed within an epoch
skips the batches it has trained on and continues with the same weights, optimiser
state, running means and torch RNG state as the run that stopped.
"""

from __future__ import annotations

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

from masknet.errors import MaskNetError
from masknet.runtime import default_precision, resolve_device
from masknet.training.distributed import init_distributed
from masknet.training.epoch import (
    RunState,
    Saver,
    end_epoch,
    resume_run,
    stop_on_sigterm,
    train_epoch,
)

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
    checkpoint_minutes: float | None = None  # also save within an epoch this often
    extra: dict = field(default_factory=dict)


def _check_config(config: TrainConfig, n_train: int) -> None:
    if n_train < config.batch_size:
        raise MaskNetError(
            f"{n_train} training shapes are fewer than one batch of {config.batch_size}; "
            "lower --batch-size or --val-fraction"
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
    rank, world, joined = init_distributed(device)
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

    model, train_model, optimizer = _build_model(task, config, init_weights, device, world)
    run = RunState()
    if resume and ckpt_path.exists():
        run = resume_run(ckpt_path, model, optimizer, device, run_info, config.epochs, lead)
    elif resume and lead:
        print(f"no checkpoint in {out}: starting a fresh run", file=sys.stderr)

    train_set = train_points[train_idx]
    val_batches = (
        task.val_batches(train_points[val_idx], config.val_pairs, config.batch_size, config.seed)
        if len(val_idx) or (config.val_fraction > 0 and not len(train_points))
        else []
    )
    autocast = torch.autocast(device.type, dtype=torch.bfloat16, enabled=precision == "bf16")
    saver = Saver(out / CHECKPOINT, model, optimizer, run, run_info, config, lead and world == 1)
    with stop_on_sigterm(enabled=world == 1) as stop:
        for epoch in range(run.epoch, config.epochs):
            epoch_start = time.perf_counter()
            means = train_epoch(
                task,
                train_model,
                optimizer,
                train_set,
                config,
                epoch,
                run,
                saver,
                stop,
                device,
                lead,
                world,
                rank,
            )
            if means is None:  # stopped within the epoch, where it stands saved
                break
            if end_epoch(
                task,
                model,
                run,
                saver,
                means,
                val_batches,
                config,
                epoch,
                epoch_start,
                device,
                autocast,
                lead,
                world,
            ):
                break
    return run.history


def _build_model(
    task: Task,
    config: TrainConfig,
    init_weights: nn.Module | None,
    device: torch.device,
    world: int,
) -> tuple[nn.Module, nn.Module, torch.optim.Optimizer]:
    """(model, the module to train, its Adam): the task's model, seeded, on ``device`` and
    started from ``init_weights``; with several processes the trained module wraps it in
    DistributedDataParallel (and its BatchNorm syncs across GPUs), while the model itself
    is what is saved and validated."""
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
    return model, train_model, optimizer


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

"""One epoch of the training loop, and the run state a checkpoint carries between epochs
and within one.

:func:`train_epoch` runs an epoch's steps from where the run stands (skipping the batches
trained before a stop: pairs are a pure function of seed, epoch and batch) and saves
within the epoch when :class:`Saver` says it is due or SIGTERM asked to stop;
:func:`end_epoch` validates, logs, draws the curve and checkpoints a finished epoch.
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import signal
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import nn

from masknet._atomic import atomic_target
from masknet._extras import progress_bar
from masknet.errors import MaskNetError
from masknet.runtime import default_precision
from masknet.training.checkpoint import load_checkpoint, save_checkpoint
from masknet.training.distributed import broadcast_flag, mean_over_processes

if TYPE_CHECKING:
    from masknet.training.loop import Task, TrainConfig

__all__ = [
    "Progress",
    "RunState",
    "Saver",
    "end_epoch",
    "learning_rate",
    "resume_run",
    "stop_on_sigterm",
    "train_epoch",
]


# Settings that may change between a run and its --resume; any other change is refused,
# because it would change the data split, the pairs or the model being continued.
RESUMABLE_CHANGES = {"epochs", "max_minutes", "threads", "device", "checkpoint_minutes"}


def check_resumable(path: Path, saved: dict | None, current: dict) -> None:
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


@dataclass
class Progress:
    """Where an epoch stopped part-way stands: batches trained, running sums of the
    metrics, and the seconds the epoch had run."""

    step: int = 0
    count: int = 0
    sums: dict[str, float] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0


@dataclass
class RunState:
    """A run as a checkpoint stores it: epochs finished, their log rows, the best score,
    and the unfinished epoch's progress."""

    epoch: int = 0
    history: list[dict] = field(default_factory=list)
    best: float = -math.inf
    progress: Progress = field(default_factory=Progress)
    started: float = field(default_factory=time.perf_counter)  # this invocation's start
    elapsed_before: float = 0.0  # minutes run by earlier invocations

    def elapsed_min(self) -> float:
        return self.elapsed_before + (time.perf_counter() - self.started) / 60


def resume_run(
    path: Path,
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    device: torch.device,
    run_info: dict,
    epochs: int,
    lead: bool,
) -> RunState:
    """The run stored in checkpoint ``path``, its weights and optimiser state loaded, and
    torch's RNG where it stood."""
    state = load_checkpoint(path, model, optimizer, device)
    check_resumable(path, state.get("run_info"), run_info)
    progress = Progress(**state.get("progress") or {})
    run = RunState(state["epoch"], state["history"], state["best"], progress)
    run.elapsed_before = state.get(
        "elapsed_min", run.history[-1]["elapsed_min"] if run.history else 0.0
    )
    if "torch_rng" in state:
        torch.set_rng_state(torch.tensor(state["torch_rng"], dtype=torch.uint8))
    if lead and run.epoch >= epochs:
        print(
            f"{path}: already finished {run.epoch} of {epochs} epochs; raise --epochs to "
            "train more",
            file=sys.stderr,
        )
    elif lead:
        within = f", batch {progress.step + 1}" if progress.step else ""
        print(f"resuming {path} at epoch {run.epoch + 1}{within}", file=sys.stderr)
    return run


class Saver:
    """Writes the run's checkpoint: after every epoch, and within one every
    ``checkpoint_minutes`` (when ``within`` allows it: one process)."""

    def __init__(self, path, model, optimizer, run, run_info, config, within: bool):
        self.path, self.model, self.optimizer = path, model, optimizer
        self.run, self.run_info = run, run_info
        self.every = config.checkpoint_minutes * 60 if config.checkpoint_minutes else None
        self.within = within
        self.last = time.perf_counter()

    def due(self) -> bool:
        return (
            self.within and self.every is not None and time.perf_counter() - self.last >= self.every
        )

    def open_folder(self) -> None:
        """The run's folder and its ``run.json``, made with the first file the run saves:
        a run stopped before it saved anything leaves nothing behind."""
        folder = self.path.parent
        folder.mkdir(parents=True, exist_ok=True)
        with atomic_target(folder / "run.json") as tmp:
            Path(tmp).write_text(json.dumps(self.run_info, indent=2))

    def save(self) -> None:
        self.open_folder()
        run = self.run
        state = {
            "epoch": run.epoch,
            "history": run.history,
            "best": run.best,
            "run_info": self.run_info,
            "progress": asdict(run.progress) if run.progress.step else None,
            "elapsed_min": run.elapsed_min(),
            "torch_rng": torch.get_rng_state().tolist(),
        }
        save_checkpoint(self.path, self.model, self.optimizer, state)
        self.last = time.perf_counter()


class StopFlag:
    requested = False


@contextlib.contextmanager
def stop_on_sigterm(enabled: bool):
    """A flag set by SIGTERM while the block runs (main thread, one process): the loop
    then saves where it stands and returns, instead of dying mid-epoch."""
    flag = StopFlag()
    if not enabled or threading.current_thread() is not threading.main_thread():
        yield flag
        return

    def request(signum, frame) -> None:
        flag.requested = True

    previous = signal.signal(signal.SIGTERM, request)
    try:
        yield flag
    finally:
        signal.signal(signal.SIGTERM, previous)


def train_epoch(
    task: Task,
    train_model: nn.Module,
    optimizer: torch.optim.Optimizer,
    train_set: np.ndarray,
    config: TrainConfig,
    epoch: int,
    run: RunState,
    saver: Saver,
    stop: StopFlag,
    device: torch.device,
    lead: bool,
    world: int,
    rank: int,
) -> dict[str, float] | None:
    """One epoch's steps, from ``run.progress`` on; the epoch's metric means, or None when
    a stop was requested (the checkpoint then holds the epoch's progress)."""
    lr = learning_rate(config, epoch)
    for group in optimizer.param_groups:
        group["lr"] = lr
    train_model.train()
    progress, begun = run.progress, time.perf_counter()
    seconds_before = progress.seconds
    autocast = torch.autocast(
        device.type, dtype=torch.bfloat16, enabled=_precision(config, device) == "bf16"
    )
    batches = task.train_batches(train_set, config.batch_size, config.seed, epoch)
    total = len(batches) if hasattr(batches, "__len__") else len(train_set) // config.batch_size
    interactive = sys.stderr.isatty()
    bar = progress_bar(
        batches,
        total=total,
        desc=f"epoch {epoch + 1}/{config.epochs}",
        leave=interactive,
        mininterval=0.5 if interactive else 60,
        file=sys.stderr,
        disable=not lead,
    )
    for index, batch in enumerate(bar):
        if index < progress.step:
            continue  # trained before the run stopped: the same pairs, skipped
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
        progress.step, progress.count = index + 1, progress.count + 1
        for key, value in {"loss": loss_value, **metrics}.items():
            progress.sums[key] = progress.sums.get(key, 0.0) + value
            progress.counts[key] = progress.counts.get(key, 0) + 1
        shown = {
            k: f"{progress.sums[k] / progress.counts[k]:.3f}"
            for k in (task.metric,)
            if k in progress.sums
        }
        bar.set_postfix(
            loss=f"{progress.sums['loss'] / progress.count:.4f}", **shown, refresh=False
        )
        if stop.requested or saver.due():
            progress.seconds = seconds_before + time.perf_counter() - begun
            if lead:
                saver.save()
            if stop.requested:
                bar.close()
                if lead:
                    print(
                        f"stopped by SIGTERM at epoch {epoch + 1}, batch {progress.step}: "
                        f"saved in {saver.path}; --resume continues from there",
                        file=sys.stderr,
                        flush=True,
                    )
                return None
    bar.close()
    progress.seconds = seconds_before + time.perf_counter() - begun
    return {k: v / progress.counts[k] for k, v in progress.sums.items()}


def _precision(config: TrainConfig, device: torch.device) -> str:
    return default_precision(device) if config.precision == "auto" else config.precision


def end_epoch(
    task: Task,
    model: nn.Module,
    run: RunState,
    saver: Saver,
    means: dict[str, float],
    val_batches: list,
    config: TrainConfig,
    epoch: int,
    epoch_start: float,
    device: torch.device,
    autocast,
    lead: bool,
    world: int,
) -> bool:
    """Validate, log, export the weights and checkpoint a finished epoch; True when the
    time budget says to stop."""
    if world > 1:
        means = mean_over_processes(means, device)
    row = {"epoch": epoch + 1, "lr": learning_rate(config, epoch)}
    row.update({f"train_{k}": v for k, v in means.items()})
    stop = False
    if lead:
        row.update(
            {f"val_{k}": v for k, v in validate(task, model, val_batches, device, autocast).items()}
        )
        row["epoch_min"] = run.progress.seconds / 60
        run.epoch, run.progress = epoch + 1, Progress()
        row["elapsed_min"] = run.elapsed_min()
        run.history.append(row)
        score = row[f"val_{task.metric}"] if val_batches else row[f"train_{task.metric}"]
        score = score if task.maximize else -score
        saver.open_folder()
        meta = {"epoch": epoch + 1, **saver.run_info, "val": row}
        if score > run.best:
            run.best = score
            task.export(model, saver.path.parent / "best.safetensors", meta)
        task.export(model, saver.path.parent / "last.safetensors", meta)
        saver.save()
        write_csv(run.history, saver.path.parent / "log.csv")
        plot_curve(run.history, saver.path.parent / "curve.png", task.metric)
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
            spent = (time.perf_counter() - run.started) / 60
            if spent + row["epoch_min"] > config.max_minutes:
                print(f"stopping: time budget of {config.max_minutes} min reached", file=sys.stderr)
                stop = True
    else:
        run.epoch, run.progress = epoch + 1, Progress()
    if world > 1:
        stop = broadcast_flag(stop, device)
    return stop


def plot_curve(history: list[dict], path: Path, metric: str) -> None:
    """The learning curve as a picture (loss and ``metric``, training and validation, per
    epoch), where matplotlib is installed (the ``viz`` extra); skipped otherwise."""
    from masknet.viz import plot_learning_curve

    try:
        plot_learning_curve(history, path, metric)
    except MaskNetError:  # matplotlib missing: the log holds the same numbers
        return


@torch.no_grad()
def validate(
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


def write_csv(rows: list[dict], path: Path) -> None:
    with atomic_target(path) as tmp, open(tmp, "w", newline="") as fh:
        # Every key of every row, in first-seen order: a mixed task's kinds vary by epoch.
        writer = csv.DictWriter(fh, fieldnames=list(dict.fromkeys(k for r in rows for k in r)))
        writer.writeheader()
        writer.writerows(rows)


def learning_rate(config: TrainConfig, epoch: int) -> float:
    if config.lr_schedule == "constant":
        return config.lr
    progress = epoch / max(1, config.epochs - 1)
    return config.min_lr + 0.5 * (config.lr - config.min_lr) * (1 + math.cos(math.pi * progress))

"""Several training processes under torchrun: joining the group, and agreeing on metrics
and on when to stop."""

from __future__ import annotations

import os

import torch

__all__ = ["broadcast_flag", "init_distributed", "mean_over_processes"]


def init_distributed(device: torch.device) -> tuple[int, int, bool]:
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


def mean_over_processes(sums: dict[str, float], device: torch.device) -> dict[str, float]:
    """Average per-process metric means, so rank 0 logs the whole batch."""
    import torch.distributed as dist

    keys = sorted(sums)
    on = device if device.type == "cuda" else "cpu"
    values = torch.tensor([sums[k] for k in keys], dtype=torch.float64, device=on)
    dist.all_reduce(values)
    return {k: float(v) / dist.get_world_size() for k, v in zip(keys, values, strict=True)}


def broadcast_flag(flag: bool, device: torch.device) -> bool:
    """Rank 0's decision, on every rank (so all stop at the same epoch)."""
    import torch.distributed as dist

    value = torch.tensor([int(flag)], device=device if device.type == "cuda" else "cpu")
    dist.broadcast(value, src=0)
    return bool(value.item())

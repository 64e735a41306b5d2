"""Where and in what precision to run: device and bf16 detection, shared by
training and inference."""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Iterator
from pathlib import Path

import torch

from masknet.errors import MaskNetError

__all__ = ["default_precision", "resolve_device", "threads_for"]


def resolve_device(device: str) -> torch.device:
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise MaskNetError(f"device {device!r} requested but CUDA is not available")
    try:
        return torch.device(device)
    except RuntimeError:
        raise MaskNetError(f"unknown device {device!r}; use auto, cpu, cuda or cuda:N") from None


def default_precision(device: torch.device | str = "cpu") -> str:
    """``"bf16"`` where the hardware runs it natively (CUDA with bf16, CPUs with
    AVX512-BF16 or AMX), else ``"fp32"``."""
    return _default_precision(torch.device(device).type)


@functools.lru_cache(maxsize=4)
def _default_precision(device_type: str) -> str:
    if device_type == "cuda":
        return "bf16" if torch.cuda.is_bf16_supported() else "fp32"
    if device_type != "cpu":
        return "fp32"
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        return "fp32"
    return "bf16" if ("avx512_bf16" in flags or "amx_bf16" in flags) else "fp32"


# Below this many distance evaluations, thread start-up costs more than it saves.
SMALL_WORK = 8_000_000


@contextlib.contextmanager
def threads_for(work: int) -> Iterator[None]:
    """Run small CPU problems (``work`` below :data:`SMALL_WORK` operations) on one thread.

    Small nearest-neighbour searches and 3x3 solves are dominated by thread overhead:
    one ICP of a 717-point source on a 1,024-point template runs about twice as fast
    on one thread as on two (docs/RESULTS.md). Larger problems keep torch's setting.
    """
    before = torch.get_num_threads()
    if work >= SMALL_WORK or before == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)

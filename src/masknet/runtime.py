"""Where and in what precision to run: device and bf16 detection, shared by
training and inference."""

from __future__ import annotations

import functools
from pathlib import Path

import torch

from masknet.errors import MaskNetError

__all__ = ["default_precision", "resolve_device"]


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

"""Where and in what precision to run: device and bf16 detection, shared by
training and inference; and the threads of numpy's linear algebra around single pairs."""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import torch

from masknet.errors import MaskNetError

__all__ = ["default_precision", "resolve_device", "small_blas"]

F = TypeVar("F", bound=Callable[..., Any])


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


@functools.lru_cache(maxsize=1)
def cpu_name() -> str:
    """The CPU's model name (Linux's ``/proc/cpuinfo``), else the platform's processor or
    machine string: what a timing or a model card states as its machine."""
    import platform

    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def small_blas(function: F) -> F:
    """Decorate an entry point whose numpy linear algebra works on small arrays (batches of
    3x3 SVDs, a few hundred points): numpy's BLAS runs single-threaded within it.

    On such arrays BLAS threads never pay, and their spinning competes with the threads of
    torch and of the KD-tree for the same cores: on 2 cores ``method="robust"`` took 103 ms
    per 512-point scan pair with them and 62 ms without, and the network's pass inside it
    14.5 ms against 5.8 ms. Torch's own BLAS, and numpy's outside the call, keep their
    threads. Without ``threadpoolctl`` the call runs as it is."""

    @functools.wraps(function)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        blas = _numpy_blas()
        if blas is None:
            return function(*args, **kwargs)
        with blas.limit(limits=1):
            return function(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


@functools.cache
def _numpy_blas() -> Any:
    """threadpoolctl's handle on every BLAS loaded but torch's, or None."""
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:
        return None
    torch_dir = str(Path(torch.__file__).parent)
    loaded = ThreadpoolController().select(user_api="blas")
    paths = [lib.filepath for lib in loaded.lib_controllers]
    kept = [path for path in paths if not path.startswith(torch_dir)]
    return loaded.select(filepath=kept) if kept else None

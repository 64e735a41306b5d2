"""safetensors weights for every network: one save/load implementation.

A model class mixes in :class:`SafetensorsWeights` and sets ``weights_prefix``
(the shipped files are ``resources/weights/<prefix><name>.safetensors``). Its
constructor keyword arguments live in ``self.config`` and travel in the file's
metadata under ``<prefix>config``, so a file rebuilds its own architecture.
Loading never unpickles.
"""

from __future__ import annotations

import json
import os
from importlib import resources
from pathlib import Path
from typing import TypeVar

import torch
from safetensors.torch import load_file, save_file

from masknet._atomic import atomic_target
from masknet.errors import MaskNetError

__all__ = ["STORAGE_DTYPES", "SafetensorsWeights", "read_metadata", "shipped_weights_path"]

M = TypeVar("M", bound="SafetensorsWeights")

# How floating-point tensors may be stored on disk; loading always gives fp32.
STORAGE_DTYPES = {"fp32": torch.float32, "fp16": torch.float16}


def shipped_weights_path(filename: str) -> Path:
    """Path of a file in the package's ``resources/weights/`` folder."""
    return Path(str(resources.files("masknet") / "resources" / "weights" / filename))


def read_metadata(path: str | os.PathLike) -> dict[str, str]:
    """The metadata of a safetensors weights file (its ``<prefix>config`` keys say which
    network it holds); MaskNetError if it is missing or unreadable. Never unpickles."""
    path = Path(path)
    if not path.exists():
        hint = (
            ""
            if path.suffix
            else " (shipped weights go by name: --weights NAME; in Python, pretrained(NAME))"
        )
        raise MaskNetError(f"{path}: weights file not found{hint}")
    try:
        from safetensors import safe_open

        with safe_open(str(path), framework="pt") as f:
            return f.metadata() or {}
    except Exception as exc:  # safetensors raises its own error types
        raise MaskNetError(f"{path}: not a readable safetensors file ({exc})") from None


class SafetensorsWeights:
    """Mixin for ``nn.Module`` subclasses: ``save``, ``from_file`` and ``pretrained``."""

    weights_prefix: str = ""  # e.g. "masknet_"; also names the config metadata key
    config: dict

    @classmethod
    def _config_key(cls) -> str:
        return f"{cls.weights_prefix}config"

    def save(
        self, path: str | os.PathLike, metadata: dict | None = None, storage: str = "fp32"
    ) -> None:
        """Write the weights as safetensors (atomically), with the architecture in the metadata.

        ``storage="fp16"`` stores floating-point tensors in half precision (half the file;
        :meth:`from_file` loads them back into the fp32 network) and records it in the
        metadata under ``storage``. A value beyond fp16's range is a MaskNetError.
        """
        if storage not in STORAGE_DTYPES:
            raise MaskNetError(f"storage must be one of {sorted(STORAGE_DTYPES)}, got {storage!r}")
        meta = {self._config_key(): json.dumps(self.config)}
        meta.update(
            {k: v if isinstance(v, str) else json.dumps(v) for k, v in (metadata or {}).items()}
        )
        meta["storage"] = storage
        dtype = STORAGE_DTYPES[storage]
        state = self.state_dict()  # type: ignore[attr-defined]
        tensors = {}
        for key, value in state.items():
            value = value.detach().cpu()
            if value.is_floating_point():
                value = value.to(dtype)
                if not bool(torch.isfinite(value).all()):
                    raise MaskNetError(f"{path}: {key} does not fit in {storage} storage")
            tensors[key] = value.contiguous()
        with atomic_target(path) as tmp:
            save_file(tensors, tmp, meta)

    @classmethod
    def from_file(
        cls: type[M], path: str | os.PathLike, map_location: str | torch.device = "cpu"
    ) -> M:
        """Load weights written by :meth:`save` (safetensors; never unpickles). Weights
        stored in fp16 are loaded into the fp32 network."""
        path = Path(path)
        kind = cls.__name__
        meta = read_metadata(path)
        try:
            state = load_file(str(path), device=str(map_location))
        except Exception as exc:  # safetensors raises its own error types
            raise MaskNetError(f"{path}: not a readable safetensors file ({exc})") from None
        key = cls._config_key()
        if key not in meta and any(k.endswith("checkpoint") for k in meta):
            raise MaskNetError(
                f"{path}: a training checkpoint (for masknet train --resume); the weights "
                "to use are best.safetensors beside it"
            )
        if key not in meta:
            others = sorted(k for k in meta if k.endswith("config"))
            hint = (
                f" (it holds {others[0].removesuffix('config').rstrip('_')} weights)"
                if others
                else ""
            )
            raise MaskNetError(f"{path}: not {kind} weights: no {key} metadata{hint}")
        try:
            model = cls(**json.loads(meta[key]))
        except (ValueError, TypeError) as exc:
            raise MaskNetError(f"{path}: bad {key} metadata ({exc})") from None
        try:
            model.load_state_dict(state)  # type: ignore[attr-defined]
        except RuntimeError as exc:
            raise MaskNetError(
                f"{path}: weights do not fit the {kind} architecture ({exc})"
            ) from None
        return model.to(map_location).eval()  # type: ignore[attr-defined]

    @classmethod
    def pretrained(
        cls: type[M], name: str = "modelnet40", map_location: str | torch.device = "cpu"
    ) -> M:
        """Shipped weights, loaded offline from the package (model cards beside them)."""
        path = shipped_weights_path(f"{cls.weights_prefix}{name}.safetensors")
        if not path.exists():
            shipped = sorted(
                p.stem.removeprefix(cls.weights_prefix)
                for p in path.parent.glob(f"{cls.weights_prefix}*.safetensors")
            )
            raise MaskNetError(
                f"no shipped {cls.__name__} weights named {name!r}; available: {shipped or 'none'}"
            )
        return cls.from_file(path, map_location)

"""Training checkpoints as safetensors: model, optimizer and run state, nothing pickled.

A checkpoint is one ``.safetensors`` file. Its tensors are the model's state
(``model/<name>``) and the optimizer's per-parameter state (``optim/<index>/<key>``);
its metadata holds, as JSON, the optimizer's parameter groups and the loop's own state
(epoch, history, best score, run settings). It is small enough to commit beside a run's
log, so that a long run can be resumed on another machine.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file
from torch import nn

from masknet._atomic import atomic_target
from masknet.errors import MaskNetError

__all__ = ["load_checkpoint", "save_checkpoint"]

_STATE_KEY = "masknet_checkpoint"


def _json_default(value: Any) -> Any:
    if isinstance(value, tuple):
        return list(value)
    raise TypeError(f"cannot store {type(value).__name__} in a checkpoint")


def save_checkpoint(
    path: str | Path, model: nn.Module, optimizer: torch.optim.Optimizer, state: dict
) -> None:
    """Write model, optimizer and ``state`` (JSON-serialisable) to ``path``, atomically."""
    tensors = {f"model/{k}": v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    optim = optimizer.state_dict()
    scalars: dict[str, dict[str, float]] = {}
    for index, values in optim["state"].items():
        for key, value in values.items():
            if isinstance(value, torch.Tensor):
                tensors[f"optim/{index}/{key}"] = value.detach().cpu().contiguous()
            else:
                scalars.setdefault(str(index), {})[key] = value
    meta = {
        _STATE_KEY: json.dumps(state, default=_json_default),
        "param_groups": json.dumps(optim["param_groups"], default=_json_default),
        "optim_scalars": json.dumps(scalars),
    }
    with atomic_target(path) as tmp:
        save_file(tensors, tmp, meta)


def load_checkpoint(
    path: str | Path,
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    device: torch.device | str = "cpu",
) -> dict:
    """Restore model and optimizer from ``path``; returns the stored ``state``.

    A ``.pt`` file from earlier versions is read with ``torch.load(weights_only=True)``.

    Raises:
        MaskNetError: the file is unreadable or does not fit the model.
    """
    path = Path(path)
    try:
        if path.suffix == ".pt":
            saved = torch.load(path, map_location=device, weights_only=True)
            model.load_state_dict(saved["model"])
            optimizer.load_state_dict(saved["optimizer"])
            return {k: v for k, v in saved.items() if k not in ("model", "optimizer")}
        from safetensors import safe_open

        with safe_open(str(path), framework="pt") as f:
            meta = f.metadata() or {}
        tensors = load_file(str(path), device=str(device))
        model.load_state_dict(
            {k.removeprefix("model/"): v for k, v in tensors.items() if k.startswith("model/")}
        )
        per_param: dict[int, dict[str, Any]] = {}
        for key, value in tensors.items():
            if key.startswith("optim/"):
                _, index, name = key.split("/", 2)
                per_param.setdefault(int(index), {})[name] = value
        for index, values in json.loads(meta["optim_scalars"]).items():
            per_param.setdefault(int(index), {}).update(values)
        optimizer.load_state_dict(
            {"state": per_param, "param_groups": json.loads(meta["param_groups"])}
        )
        state = json.loads(meta[_STATE_KEY])
    except Exception as exc:  # safetensors, json and shape errors come in many types
        raise MaskNetError(f"{path}: cannot resume from it ({exc})") from None
    return state

"""torchrun + DistributedDataParallel (gloo, CPU): two processes train exactly as one."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import torch
from safetensors.torch import load_file

from masknet.models import PointNetLK

WORKER = Path(__file__).with_name("_ddp_worker.py")


def _run(args: list[str], env_extra: dict | None = None) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("WORLD_SIZE", "RANK", "LOCAL_RANK")}
    env |= {"OMP_NUM_THREADS": "1", **(env_extra or {})}
    done = subprocess.run(args, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]


def test_two_gloo_processes_match_one_process(tmp_path):
    single, double = tmp_path / "single", tmp_path / "ddp"
    _run([sys.executable, str(WORKER), str(single)])
    _run(
        [
            sys.executable,
            "-m",
            "torch.distributed.run",
            "--standalone",
            "--nproc_per_node",
            "2",
            str(WORKER),
            str(double),
        ]
    )
    a = load_file(str(single / "last.safetensors"))
    b = load_file(str(double / "last.safetensors"))
    assert a.keys() == b.keys()
    torch.manual_seed(0)  # fit() seeds with config.seed before building the model
    start = PointNetLK(encoder_channels=[16, 32]).double().state_dict()
    moved = max((a[key] - start[key]).abs().max().item() for key in a)
    assert moved > 1e-3  # training changed the weights...
    for key in a:  # ...and both runs changed them the same way (float64 rounding aside)
        assert (a[key] - b[key]).abs().max() < 1e-6, key
    log_single = (single / "log.csv").read_text().splitlines()
    log_double = (double / "log.csv").read_text().splitlines()
    assert len(log_single) == len(log_double) == 3  # header + 2 epochs, written by rank 0 only

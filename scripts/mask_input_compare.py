"""CrossMaskNet with and without FPFH descriptor inputs, trained side by side at equal steps.

Both networks start from the same seed and see the same training batches (the relay's
recipe: BCE, batch 32, Adam lr 5e-4, fp32; the relay's cosine over 40 epochs is flat over
these first steps, so the rate is held at 5e-4), one step each in turn, in one process on
``--threads`` threads. Each network's training CPU-seconds (process time of its own
steps: descriptors included) are counted apart; every ``--val-every`` steps both are
scored on the same validation pairs (held-out training shapes, as ``masknet train``).

    python scripts/mask_input_compare.py --data .../modelnet40_1024_int16.npz \\
        --steps 120 --val-every 20 --out /tmp/desc_compare/curve.csv

Writes one CSV row per (network, validation): step, train CPU-s, val top-k precision.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import torch

from masknet.cli import run_script
from masknet.data import load_modelnet40
from masknet.training import MaskNetTask
from masknet.training.loop import split_train_val

CANDIDATES = {"xyz": {}, "fpfh": {"descriptors": "fpfh"}}


def _validate(task: MaskNetTask, model: torch.nn.Module, batches: list) -> float:
    """Mean top-k precision of ``model`` over validation ``batches``."""
    model.eval()
    with torch.no_grad():
        values = [task.step(model, batch, torch.device("cpu"))[1]["precision"] for batch in batches]
    model.train()
    return float(sum(values) / len(values))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True)
    p.add_argument("--steps", type=int, default=120)
    p.add_argument("--val-every", type=int, default=20)
    p.add_argument("--val-pairs", type=int, default=256)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", required=True)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    points = load_modelnet40(args.data, "train").points
    train_idx, val_idx = split_train_val(len(points), 0.1, 0)
    runs = {}
    for name, config in CANDIDATES.items():
        task = MaskNetTask(network="crossmasknet", loss="bce", model_config=config)
        torch.manual_seed(0)
        model = task.build_model()
        runs[name] = {
            "task": task,
            "model": model,
            "opt": torch.optim.Adam(model.parameters(), lr=5e-4),
            "cpu": 0.0,
        }
    val = runs["xyz"]["task"].val_batches(points[val_idx], args.val_pairs, 32, 0)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["network", "step", "train_cpu_s", "val_precision", "train_loss"])
        batches = runs["xyz"]["task"].train_batches(points[train_idx], 32, 0, 0)
        losses = {name: 0.0 for name in runs}
        for step, batch in enumerate(batches, start=1):
            for name, run in runs.items():
                start = time.process_time()
                loss, _ = run["task"].step(run["model"], batch, torch.device("cpu"))
                run["opt"].zero_grad()
                loss.backward()
                run["opt"].step()
                run["cpu"] += time.process_time() - start
                losses[name] = round(loss.item(), 4)
            if step % args.val_every == 0 or step == args.steps:
                for name, run in runs.items():
                    precision = _validate(run["task"], run["model"], val)
                    row = [name, step, round(run["cpu"], 1), round(precision, 4), losses[name]]
                    out.writerow(row)
                    print(*row, flush=True)
                f.flush()
            if step == args.steps:
                break
    for name, run in runs.items():
        run["model"].save(Path(args.out).with_name(f"{name}.safetensors"))


if __name__ == "__main__":
    run_script(main)

"""Batch-1 timing in one run: masknet's ICP against Open3D's, the paper's Mask-ICP with its
MaskNet and ICP stages apart, and the default and ``robust`` against Open3D RANSAC + ICP.

    python scripts/speed.py --data $MASKNET_DATA --pairs 50 --out docs/results/speed.json

ModelNet40 test pairs (the paper's protocol, seed 0), single-pair ``register`` calls,
median over the pairs after 5 warm-up calls, 2 threads.
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np
import torch

from masknet import register
from masknet.cli import run_script
from masknet.data import PairConfig, load_modelnet40, make_test_pairs
from masknet.evaluation.registration import pair_arrays
from masknet.io import write_text_atomic

PIPELINES = {
    "ICP (masknet)": {"method": "icp", "use_mask": False},
    "ICP (Open3D)": {"method": "open3d-icp", "use_mask": False},
    "Mask-ICP (the paper's, one round)": {"method": "icp"},
    "Mask-ICP with Open3D's ICP": {"method": "open3d-icp"},
    "the default (auto)": {},
    "robust": {"method": "robust"},
    "Open3D RANSAC + 10 ICP (voxel 0.05, all threads)": {
        "method": "open3d-ransac",
        "use_mask": False,
        "refine_iterations": 10,
        "repeatable": False,
    },
}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True)
    p.add_argument("--pairs", type=int, default=50)
    p.add_argument("--out")
    args = p.parse_args()
    torch.set_num_threads(2)
    points = load_modelnet40(args.data, "test").points
    tpl, src, _ = pair_arrays(make_test_pairs(points, args.pairs, PairConfig(), 0))
    rows = []
    for name, kwargs in PIPELINES.items():
        for i in range(5):
            register(tpl[i], src[i], **kwargs)
        total, mask, reg = [], [], []
        for i in range(len(tpl)):
            tic = time.perf_counter()
            result = register(tpl[i], src[i], **kwargs)
            total.append(time.perf_counter() - tic)
            mask.append(result.times["mask"])
            reg.append(result.times["register"] + result.times["refine"])
        row = {
            "pipeline": name,
            "ms_median": 1e3 * float(np.median(total)),
            "ms_mask": 1e3 * float(np.median(mask)),
            "ms_register": 1e3 * float(np.median(reg)),
        }
        rows.append(row)
        print(row, flush=True)
    machine = f"{platform.machine()}, {torch.get_num_threads()} threads, torch {torch.__version__}"
    if args.out:
        write_text_atomic(args.out, json.dumps({"machine": machine, "rows": rows}, indent=1))


if __name__ == "__main__":
    run_script(main)

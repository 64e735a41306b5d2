"""Time the template-mask networks at batch 1, in one run: the shipped MaskNet and CrossMaskNet.

    python scripts/mask_speed.py [--weights relay/crossmasknet_modelnet40/last.safetensors]

One ModelNet40-sized pair (1,024 template points, 717 source points), ``predict`` called
``--calls`` times per network and precision after a warm-up, networks alternating call by
call so that both see the same machine; prints the median and the 10th and 90th percentiles
in milliseconds. CrossMaskNet's time does not depend on its weights: without ``--weights`` it
runs freshly initialised.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from masknet.cli import run_script


def main() -> None:
    import torch

    from masknet.models import CrossMaskNet, MaskNet

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weights", help="CrossMaskNet weights (default: fresh weights)")
    parser.add_argument("--calls", type=int, default=50, help="timed calls per network")
    parser.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(0)
    template = rng.normal(size=(1024, 3))
    source = template[:717] + 0.1
    cross = CrossMaskNet.from_file(args.weights) if args.weights else CrossMaskNet().eval()
    networks = {"MaskNet (shipped)": MaskNet.pretrained(), "CrossMaskNet": cross}
    calls = {
        (name, precision): (lambda n=net, p=precision: n.predict(template, source, precision=p))
        for name, net in networks.items()
        for precision in ("fp32", "bf16")
    }
    for call in calls.values():
        for _ in range(3):
            call()
    times: dict = {key: [] for key in calls}
    for _ in range(args.calls):
        for key, call in calls.items():
            start = time.perf_counter()
            call()
            times[key].append(1000 * (time.perf_counter() - start))
    print(f"batch 1, 1,024 / 717 points, {args.threads} threads, torch {torch.__version__}")
    print("| network | precision | median ms | p10 | p90 |")
    print("|---|---|---|---|---|")
    for (name, precision), values in times.items():
        p10, median, p90 = np.percentile(values, [10, 50, 90])
        print(f"| {name} | {precision} | {median:.1f} | {p10:.1f} | {p90:.1f} |")


if __name__ == "__main__":
    run_script(main)

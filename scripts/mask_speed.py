"""Time the template-mask networks at batch 1, in one run: the shipped MaskNet and CrossMaskNet.

    python scripts/mask_speed.py [--weights relay/crossmasknet_modelnet40/last.safetensors]
        [--descriptors] [--data .../modelnet40_1024_int16.npz]

One ModelNet40-sized pair (1,024 template points, 717 source points; a ModelNet40 test
pair with ``--data``, else a random one), ``predict`` called
``--calls`` times per network and precision after a warm-up, networks alternating call by
call so that both see the same machine; prints the median and the 10th and 90th percentiles
in milliseconds. CrossMaskNet's time does not depend on its weights: without ``--weights`` it
runs freshly initialised. ``--descriptors`` adds CrossMaskNet with FPFH descriptor inputs
(``descriptors="fpfh"``, fresh weights, fp32 only: their time included) and the
descriptors alone.
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
    parser.add_argument("--descriptors", action="store_true", help="also FPFH inputs")
    parser.add_argument("--data", help="ModelNet40 .npz: time on its first test pair")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    template, source = _pair(args.data)
    cross = CrossMaskNet.from_file(args.weights) if args.weights else CrossMaskNet().eval()
    networks = {"MaskNet (shipped)": MaskNet.pretrained(), "CrossMaskNet": cross}
    calls = {
        (name, precision): (lambda n=net, p=precision: n.predict(template, source, precision=p))
        for name, net in networks.items()
        for precision in ("fp32", "bf16")
    }
    if args.descriptors:
        calls |= _descriptor_calls(template, source)
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


def _pair(data: str | None) -> tuple[np.ndarray, np.ndarray]:
    """The timed pair: the first ModelNet40 test pair of ``data``, or a random one."""
    if data is None:
        template = np.random.default_rng(0).normal(size=(1024, 3))
        return template, template[:717] + 0.1
    from masknet.data import PairConfig, load_modelnet40, make_test_pairs

    pairs = make_test_pairs(load_modelnet40(data, "test").points, 1, PairConfig(), seed=0)
    return pairs.template[0].numpy(), pairs.source[0].numpy()


def _descriptor_calls(template: np.ndarray, source: np.ndarray) -> dict:
    """CrossMaskNet with FPFH inputs (fp32) and the descriptors alone, as timed calls."""
    import torch

    from masknet.models import CrossMaskNet
    from masknet.models.descriptors import pair_descriptors

    net = CrossMaskNet(descriptors="fpfh").eval()
    pair = [torch.as_tensor(c, dtype=torch.float32)[None] for c in (template, source)]
    return {
        ("CrossMaskNet, FPFH inputs", "fp32"): lambda: net.predict(
            template, source, precision="fp32"
        ),
        ("FPFH descriptors alone", "-"): lambda: pair_descriptors(*pair),
    }


if __name__ == "__main__":
    run_script(main)

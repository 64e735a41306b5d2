"""How well ``evaluate_registration``'s fitness tells a good registration from a failed one.

    python scripts/fit_calibration.py --data $MASKNET_DATA --pairs 300 --out docs/results/fit_calibration.json

Seeded ModelNet40 test pairs (the paper's protocol: 30% missing, <= 45 degrees), plain ICP
(so that results range from exact to far off), then the fitness of each result at several
inlier distances, in template spacings: its median over results within 2 degrees of the
truth and over those more than 10 degrees off.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from masknet import evaluate_registration, register
from masknet.cli import run_script
from masknet.data import PairConfig, load_modelnet40, make_test_pairs
from masknet.evaluation.registration import pair_arrays, pose_errors
from masknet.geometry.clouds import median_spacing
from masknet.io import write_text_atomic


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True)
    p.add_argument("--pairs", type=int, default=300)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--spacings", default="1,1.5,2,3")
    p.add_argument("--out")
    args = p.parse_args()
    torch.set_num_threads(2)
    pairs = make_test_pairs(
        load_modelnet40(args.data, "test").points, args.pairs, PairConfig(), args.seed
    )
    template, source, truth = pair_arrays(pairs)
    result = register(template, source, use_mask=False)
    error = pose_errors(result.transform, truth)[0]
    good, bad = error < 2, error > 10
    spacing = np.array([median_spacing(t) for t in template])
    rows = []
    for factor in [float(f) for f in args.spacings.split(",")]:
        fitness = np.array(
            [
                evaluate_registration(
                    template=t, source=s, transform=tf, max_correspondence_distance=factor * sp
                ).fitness
                for t, s, tf, sp in zip(template, source, result.transform, spacing, strict=True)
            ]
        )
        rows.append(
            {
                "spacings": factor,
                "results_within_2_deg": int(good.sum()),
                "median_fitness_within_2_deg": float(np.median(fitness[good])),
                "p10_fitness_within_2_deg": float(np.percentile(fitness[good], 10)),
                "results_over_10_deg": int(bad.sum()),
                "median_fitness_over_10_deg": float(np.median(fitness[bad])),
                "p90_fitness_over_10_deg": float(np.percentile(fitness[bad], 90)),
            }
        )
        print(rows[-1], flush=True)
    if args.out:
        write_text_atomic(args.out, json.dumps({"pairs": args.pairs, "rows": rows}, indent=1))


if __name__ == "__main__":
    run_script(main)

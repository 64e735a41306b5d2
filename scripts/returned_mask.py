"""Precision and recall of the mask ``register`` returns, over the results its verdict calls
likely correct: on ModelNet40 test pairs (copied points, and with noise) and on real-scan
views of the evaluation scans (copied and re-sampled points).

    python scripts/returned_mask.py [--pairs 200] [--json docs/results/returned_mask.json]

Prints a Markdown table: per set, the likely-correct results, and the mean precision,
recall and lowest precision of their masks against the true masks.
"""

from __future__ import annotations

import argparse
import json
import os

import numpy as np

from masknet.cli import run_script


def sets(pairs: int) -> dict:
    """Set name -> seeded pairs (template, source, true mask)."""
    from masknet.data import PairConfig, load_modelnet40, make_test_pairs
    from masknet.data.scans import load_scans, make_scan_test_pairs
    from masknet.data.views import ViewConfig
    from masknet.experiments.scans import scans_folder

    shapes = load_modelnet40(os.environ.get("MASKNET_DATA"), "test").points
    found = {
        "ModelNet40, copied points": make_test_pairs(shapes, pairs, PairConfig(), seed=0),
        "ModelNet40, noise 0.01": make_test_pairs(
            shapes, pairs, PairConfig(noise_sigma=0.01), seed=0
        ),
    }
    scans = load_scans(scans_folder(), quiet=True)
    for name, independent in (("copied", False), ("re-sampled", True)):
        view = ViewConfig(independent=independent)
        per_scan = max(1, pairs // len(scans))
        found[f"real-scan views, {name} points"] = make_scan_test_pairs(
            scans, per_scan, view, seed=0
        )[0]
    return found


def measure(pairs) -> dict:
    """Mean precision and recall of the returned masks of likely-correct results."""
    from masknet import assess_registration, register

    template, source = pairs.template.double().numpy(), pairs.source.double().numpy()
    truth = pairs.mask.numpy()
    rows = []
    for t, s, m in zip(template, source, truth, strict=True):
        result = register(t, s)
        if assess_registration(t, s, result.transform).verdict != "likely correct":
            continue
        hits = (result.mask & m).sum()
        rows.append((hits / max(result.mask.sum(), 1), hits / max(m.sum(), 1)))
    values = np.array(rows)
    return {
        "pairs": len(template),
        "likely_correct": len(values),
        "precision": float(values[:, 0].mean()),
        "recall": float(values[:, 1].mean()),
        "lowest_precision": float(values[:, 0].min()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=200, help="pairs per set (default 200)")
    parser.add_argument("--json", help="also write the table to this JSON file")
    args = parser.parse_args()
    table = {name: measure(pairs) for name, pairs in sets(args.pairs).items()}
    print("| set | likely correct | precision | recall | lowest precision |")
    print("|---|---|---|---|---|")
    for name, row in table.items():
        print(
            f"| {name} | {row['likely_correct']}/{row['pairs']} | {row['precision']:.4f} | "
            f"{row['recall']:.4f} | {row['lowest_precision']:.4f} |"
        )
    if args.json:
        from masknet.io import write_text_atomic

        write_text_atomic(args.json, json.dumps(table, indent=2) + "\n")


if __name__ == "__main__":
    run_script(main)

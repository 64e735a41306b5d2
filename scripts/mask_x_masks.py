"""Each Mask-X with its default mask, the paper's MaskNet, the true mask, and no mask.

    python scripts/mask_x_masks.py --data PATH --pairs 60

``--pairs`` ModelNet40 test pairs of the paper's protocol (random views keeping 70% of the
template's points, rotations up to 45 degrees, ``make_test_pairs`` with ``--seed``, default
0), the same pairs for every row. For each Mask-X method (ICP and the learned networks,
their shipped weights and default iterations), one round of ``masknet.register`` in
batches: with ``model=None`` (the default mask: the shipped CrossMaskNet), with the paper's
MaskNet (``model=MaskNet.pretrained()``), with the true mask (the template points the
source was cut from), and plain X (``use_mask=False``). Prints
one Markdown table of mean and median rotation errors in degrees; accuracy only (no times).
"""

from __future__ import annotations

import argparse

import numpy as np

from masknet import register
from masknet.cli import run_script
from masknet.data import PairConfig, load_modelnet40, make_test_pairs
from masknet.evaluation.registration import error_summary
from masknet.models import MaskNet
from masknet.registration.plan import MASK_X_METHODS, default_mask_x_model

CHUNK = 20  # pairs per register call


class TrueMasks:
    """The true template masks of a chunk of pairs, answering the mask protocol."""

    def __init__(self, masks: np.ndarray) -> None:
        self.masks = masks  # (B, N) bool

    def predict_masks(self, template: np.ndarray, source: np.ndarray, **_: object):
        """(B, N) template masks of the chunk, no source mask."""
        if template.shape[:2] != self.masks.shape:
            raise ValueError(f"true masks {self.masks.shape} for clouds {template.shape}")
        return self.masks, None


def errors(pairs, method: str, mask: str) -> dict[str, float]:
    """Rotation (and translation) errors of one method with one kind of mask over the pairs."""
    template, source = pairs.template.numpy(), pairs.source.numpy()
    truth, true_masks = pairs.transform.double().numpy(), pairs.mask.numpy().astype(bool)
    paper = MaskNet.pretrained()
    estimates = []
    for i in range(0, len(template), CHUNK):
        part = slice(i, i + CHUNK)
        kwargs = {"use_mask": mask != "none", "precision": "fp32"}
        if mask == "paper":
            kwargs["model"] = paper
        elif mask == "true":
            kwargs["model"] = TrueMasks(true_masks[part])
        result = register(template[part], source[part], method=method, **kwargs)
        estimates.append(result.transform)
    return error_summary(np.concatenate(estimates), truth)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", help="ModelNet40 folder or .npz (default: $MASKNET_DATA)")
    parser.add_argument("--pairs", type=int, default=60)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    points = load_modelnet40(args.data, "test").points
    pairs = make_test_pairs(points, args.pairs, PairConfig(), args.seed)
    default = type(default_mask_x_model()).__name__
    masks = {"default": f"{default} (default)", "paper": "paper's MaskNet", "true": "true mask"}
    masks["none"] = "no mask"
    head = " | ".join(f"{label} mean / median" for label in masks.values())
    lines = [f"| method | {head} |", "|---" * (len(masks) + 1) + "|"]
    for method in MASK_X_METHODS:
        cells = []
        for mask in masks:
            e = errors(pairs, method, mask)
            cells.append(f"{e['rot_mean']:.2f} / {e['rot_median']:.2f}")
        lines.append(f"| {method} | {' | '.join(cells)} |")
        print(lines[-1], flush=True)
    print(f"\nRotation error (degrees), {args.pairs} ModelNet40 test pairs, seed {args.seed}:\n")
    print("\n".join(lines))


if __name__ == "__main__":
    run_script(main)

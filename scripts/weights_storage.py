"""Do MaskNet weights stored in 16 bits give the same masks as in 32 bits?

    python scripts/weights_storage.py --data PATH --pairs 1000 --out docs/results/weights_storage.json
    python scripts/weights_storage.py --write docs/results/weights_storage.json

Each shipped MaskNet file (and the two-sided network) is loaded as stored (fp32), then
its floating-point tensors are rounded to bf16 and to fp16 and loaded back into an fp32
network. All three run fp32 inference on the same seeded ModelNet40 test pairs (the
paper's protocol), and the script reports, for each 16-bit format: the fraction of
template points whose top-k (k = M) label is the same as with the fp32 weights, the
fraction of pairs whose whole mask is the same, the largest score difference, and the
change in mean top-k precision. For the two-sided network the source mask (score >= 0.5)
is compared too, on pairs with 10% uniform outliers in the source.

``--write REPORT`` then stores in fp16 every shipped file whose fp16 point agreement in
that report is at least 99.9%, and adds the figures to its model card (``.json`` and
``.md``). Files already stored in fp16 are left as they are.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
import torch

from masknet.cli import run_script
from masknet.data import load_modelnet40
from masknet.data.pairs import PairConfig, make_test_pairs
from masknet.io import write_text_atomic
from masknet.models import MaskNet, TwoSidedMaskNet
from masknet.models.masknet import select_mask
from masknet.models.weights import read_metadata, shipped_weights_path

FORMATS = {"bf16": torch.bfloat16, "fp16": torch.float16}
KINDS = {
    "masknet_modelnet40": MaskNet,
    "masknet_modelnet40_seen20": MaskNet,
    "masknet_modelnet40_outliers10": MaskNet,
    "masknet_scans": MaskNet,
    "masknet2_scans": TwoSidedMaskNet,
}
NOISY = ("masknet_modelnet40_outliers10", "masknet2_scans")  # measured with 10% outliers
MIN_AGREEMENT = 0.999


def rounded_copy(model: torch.nn.Module, dtype: torch.dtype) -> torch.nn.Module:
    """``model`` as loaded back from a file that stores its tensors in ``dtype``: fp16
    through :meth:`save` and :meth:`from_file` themselves; other dtypes (bf16, which the
    package does not store) by the same cast."""
    if dtype == torch.float16:
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "w.safetensors"
            model.save(path, storage="fp16")
            return type(model).from_file(path)
    copy = type(model)(**model.config).eval()
    state = model.state_dict()
    copy.load_state_dict({k: v.to(dtype) if v.is_floating_point() else v for k, v in state.items()})
    return copy


def template_masks(model: torch.nn.Module, template: np.ndarray, source: np.ndarray):
    """(P, N) scores, (P, N) top-k masks and, for a two-sided network, (P, M) source masks."""
    if isinstance(model, TwoSidedMaskNet):
        scores, source_scores = model.predict(template, source, precision="fp32")
        source_mask = source_scores >= 0.5
    else:
        scores, source_mask = model.predict(template, source, precision="fp32"), None
    mask = select_mask(torch.from_numpy(scores), k=source.shape[1]).numpy()
    return scores, mask, source_mask


def compare(model: torch.nn.Module, pairs, truth: np.ndarray) -> dict:
    template, source = pairs.template.numpy(), pairs.source.numpy()
    ref_scores, ref_mask, ref_source = template_masks(model, template, source)
    k = source.shape[1]
    ref_precision = (ref_mask & truth).sum(1) / k
    rows = {}
    for name, dtype in FORMATS.items():
        scores, mask, source_mask = template_masks(rounded_copy(model, dtype), template, source)
        precision = (mask & truth).sum(1) / k
        row = {
            "point_agreement": float((mask == ref_mask).mean()),
            "pairs_identical": float((mask == ref_mask).all(1).mean()),
            "max_score_difference": float(np.abs(scores - ref_scores).max()),
            "topk_precision_fp32": float(ref_precision.mean()),
            "topk_precision": float(precision.mean()),
        }
        if source_mask is not None:
            row["source_point_agreement"] = float((source_mask == ref_source).mean())
        rows[name] = row
        print(f"  {name}: {row}", flush=True)
    return rows


def storage_text(name: str, row: dict, pairs: int) -> str:
    """The model card's storage paragraph, from one file's fp16 row of the report."""
    outliers = " with 10% uniform outliers in the source" if name in NOISY else ""
    text = (
        "Stored in **fp16** (half the size of fp32); `from_file` loads it into the fp32 "
        f"network. On {pairs:,} seeded ModelNet40 test pairs{outliers}, fp32 inference with the "
        f"fp16-stored weights gives the same top-k label as the fp32 weights for "
        f"{100 * row['point_agreement']:.2f}% of template points (largest score change "
        f"{row['max_score_difference']:.4f}); mean top-k precision {row['topk_precision']:.4f} "
        f"against {row['topk_precision_fp32']:.4f}"
    )
    if "source_point_agreement" in row:
        text += f"; source-mask agreement {100 * row['source_point_agreement']:.2f}%"
    return text + ". Measured by `scripts/weights_storage.py`."


def write_fp16(report_path: Path) -> None:
    """Store each file in fp16 where the report allows it, and note it in its card."""
    report = json.loads(report_path.read_text())
    for name, rows in report["files"].items():
        path = shipped_weights_path(f"{name}.safetensors")
        meta = read_metadata(path)
        row = rows["fp16"]
        if meta.get("storage") == "fp16" or row["point_agreement"] < MIN_AGREEMENT:
            print(
                f"{name}: left as it is (storage {meta.get('storage', 'fp32')}, "
                f"fp16 agreement {row['point_agreement']:.5f})"
            )
            continue
        model = KINDS[name].from_file(path)
        # save() writes the model's config itself (the metadata keys ending in "config")
        kept = {k: v for k, v in meta.items() if not k.endswith("config")}
        model.save(path, kept, storage="fp16")
        text = storage_text(name, row, report["pairs"])
        card = path.with_suffix(".json")
        if card.exists():
            data = json.loads(card.read_text())
            data["storage"] = {"dtype": "fp16", **row, "pairs": report["pairs"]}
            write_text_atomic(card, json.dumps(data, indent=2) + "\n")
        markdown = path.with_suffix(".md")
        lines = markdown.read_text().splitlines()
        first = next(i for i, line in enumerate(lines) if line.startswith("## "))
        lines[first:first] = ["## Storage", "", text, ""]
        write_text_atomic(markdown, "\n".join(lines) + "\n")
        print(f"{name}: stored in fp16, card updated")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", help="ModelNet40 folder or .npz (default: $MASKNET_DATA)")
    parser.add_argument("--pairs", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("docs/results/weights_storage.json"))
    parser.add_argument("--write", type=Path, metavar="REPORT", help="store in fp16 (see above)")
    args = parser.parse_args()
    if args.write:
        write_fp16(args.write)
        return
    torch.set_grad_enabled(False)
    points = load_modelnet40(args.data, "test").points
    clean = make_test_pairs(points, args.pairs, PairConfig(), args.seed)
    noisy = make_test_pairs(points, args.pairs, PairConfig(outlier_ratio=0.1), args.seed)
    report = {"pairs": args.pairs, "seed": args.seed, "files": {}}
    for name, cls in KINDS.items():
        print(name, flush=True)
        pairs = noisy if name in NOISY else clean
        model = cls.from_file(shipped_weights_path(f"{name}.safetensors"))
        report["files"][name] = compare(model, pairs, pairs.mask.numpy().astype(bool))
    write_text_atomic(args.out, json.dumps(report, indent=1))


if __name__ == "__main__":
    run_script(main)

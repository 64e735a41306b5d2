"""Ship a training run's best weights inside the package, with a generated model card.

    python scripts/ship_weights.py runs/modelnet40 modelnet40 --data PATH
    python scripts/ship_weights.py runs/seen20 modelnet40_seen20 --data PATH

Every figure on the card comes from the run folder (run.json, log.csv) or is
measured here on ``--pairs`` (default 1,000) seeded ModelNet40 *test* pairs for each
of all, seen and unseen categories; nothing is typed by hand.
"""

from __future__ import annotations

import argparse
import csv
import json
import platform
import shutil
from pathlib import Path

import torch

from masknet.data import PairConfig, load_modelnet40
from masknet.evaluation.evaluate import evaluate_masknet, format_table
from masknet.models import MaskNet

WEIGHTS = Path(__file__).resolve().parents[1] / "src" / "masknet" / "resources" / "weights"


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("run", type=Path)
    parser.add_argument("name")
    parser.add_argument("--data", required=True)
    parser.add_argument("--pairs", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    run = json.loads((args.run / "run.json").read_text())
    with open(args.run / "log.csv") as fh:
        log = list(csv.DictReader(fh))
    model = MaskNet.from_file(args.run / "best.safetensors")
    best = max(log, key=lambda row: float(row["val_precision"]))
    test = load_modelnet40(args.data, "test")
    pair_config = PairConfig(**run["task"]["pairs"])
    evaluations = {}
    for subset in ("all", "seen", "unseen"):
        points = test.subset(subset).points
        evaluations[subset] = evaluate_masknet(model, points, args.pairs, args.seed, pair_config)
        print(subset, format_table(evaluations[subset].rows), sep="\n")

    WEIGHTS.mkdir(parents=True, exist_ok=True)
    target = WEIGHTS / f"masknet_{args.name}.safetensors"
    shutil.copyfile(args.run / "best.safetensors", target)
    card = {
        "name": args.name,
        "architecture": model.config,
        "training": run,
        "epochs_trained": len(log),
        "best_epoch": int(best["epoch"]),
        "training_minutes": float(log[-1]["elapsed_min"]),
        "machine": f"{platform.processor() or platform.machine()}, {torch.get_num_threads()} threads, "
        f"torch {torch.__version__}",
        "log": log,
        "test": {subset: ev.to_dict() for subset, ev in evaluations.items()},
    }
    (WEIGHTS / f"masknet_{args.name}.json").write_text(json.dumps(card, indent=2) + "\n")
    (WEIGHTS / f"masknet_{args.name}.md").write_text(render_card(card))
    print(f"wrote {target} and its model card")


def render_card(card: dict) -> str:
    train, task = card["training"]["train"], card["training"]["task"]
    pairs = task["pairs"]
    categories = train["extra"].get("categories", "all")
    rows = []
    for subset, result in card["test"].items():
        for rule, values in result["metrics"].items():
            rows.append(
                f"| {subset} | {rule} | {values['precision']:.4f} | {values['recall']:.4f} "
                f"| {values['f1']:.4f} | {values['iou']:.4f} |"
            )
    curve = "\n".join(
        f"| {r['epoch']} | {float(r['lr']):.2e} | {float(r['train_loss']):.4f} "
        f"| {float(r['train_precision']):.4f} | {float(r['val_precision']):.4f} | {float(r['epoch_min']):.1f} |"
        for r in card["log"]
    )
    return f"""# Model card: `masknet_{card["name"]}`

MaskNet (Sarode, Dhagat et al., 3DV 2020), the paper's architecture
(encoder {card["architecture"]["encoder_channels"]}, head {card["architecture"]["head_channels"]}),
trained by `masknet train` in this repository. Load it with
`MaskNet.pretrained("{card["name"]}")`.

## Training actually done
- Data: ModelNet40 training split, **{categories}** categories; {card["training"]["shapes"]["train"]} shapes
  for training and {card["training"]["shapes"]["val"]} held out of the *training* split for validation
  (the test split was never used to choose a checkpoint).
- Pairs (fresh every epoch, seeded): protocol `{pairs["protocol"]}`, keep ratio {pairs["keep_ratio"]}
  ({100 * (1 - pairs["keep_ratio"]):.0f}% missing), rotation <= {pairs["max_angle_deg"]} deg about a random axis,
  translation uniform in [-{pairs["max_translation"]}, {pairs["max_translation"]}]^3, noise sigma
  {pairs["noise_sigma"]}, outliers {pairs["outlier_ratio"]}; {task["num_points"]} template points per pair.
- Optimiser: Adam, lr {train["lr"]} ({train["lr_schedule"]} schedule, min {train["min_lr"]}), batch
  {train["batch_size"]}, {task["loss"].upper()} loss, {train["precision"]} autocast, seed {train["seed"]}.
- Epochs: {card["epochs_trained"]} (best validation epoch {card["best_epoch"]}, the one shipped),
  {card["training_minutes"]:.0f} minutes on {card["machine"]}.

## Test metrics
{card["test"]["all"]["pairs"]} seeded pairs (seed {card["test"]["all"]["seed"]}) per row group from the
ModelNet40 **test** split, same pair protocol as training, fp32 inference. Top-k uses k = M (number of source
points); random top-k is the chance baseline.

| test categories | selection | precision | recall | F1 | IoU |
|---|---|---|---|---|---|
{chr(10).join(rows)}

## Training curve
| epoch | lr | train loss | train precision | val precision | minutes |
|---|---|---|---|---|---|
{curve}

## Limits
Trained on clean, synthetic, unit-radius CAD samples with {100 * (1 - pairs["keep_ratio"]):.0f}% missing points.
Expect lower precision on real sensor data, other missing ratios, larger rotations, noise and outliers.
"""


if __name__ == "__main__":
    main()

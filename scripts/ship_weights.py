"""Ship a training run's best weights inside the package, with a generated model card.

    python scripts/ship_weights.py runs/modelnet40 modelnet40 --data PATH
    python scripts/ship_weights.py runs/seen20 modelnet40_seen20 --data PATH
    python scripts/ship_weights.py runs/ft modelnet40 --data PATH --previous OLD_CARD.json
    python scripts/ship_weights.py runs/denoise denoise_modelnet40 --data PATH --kind denoise
    python scripts/ship_weights.py runs/pointnetlk modelnet40 --data PATH --kind pointnetlk
    python scripts/ship_weights.py runs/dcp modelnet40 --data PATH --kind dcp  (prnet, pcrnet, rpmnet)

Every figure on the card comes from the run folder (run.json, log.csv) or is
measured here on ``--pairs`` (default 1,000) seeded ModelNet40 *test* pairs;
nothing is typed by hand. ``--previous`` names the card of the weights a run was
started from (``masknet train --init``), so the card states the whole training.
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


def read_run(run: Path) -> tuple[dict, list[dict]]:
    """run.json and log.csv of a training run folder."""
    info = json.loads((run / "run.json").read_text())
    with open(run / "log.csv") as fh:
        return info, list(csv.DictReader(fh))


def run_fields(name: str, run: dict, log: list[dict], previous: dict | None) -> dict:
    """The card fields that come from a training run folder alone."""
    return {
        "name": name,
        "training": run,
        "epochs_trained": len(log),
        "training_minutes": float(log[-1]["elapsed_min"]),
        "log": log,
        "previous": previous,
    }


def run_summary(run_dir: Path) -> dict:
    """The card fields of an unshipped run that a shipped one continued (``--init``)."""
    return run_fields(run_dir.name, *read_run(run_dir), previous=None)


def machine(run: dict) -> str:
    """The training machine: this one, with the run's thread setting."""
    threads = run["train"].get("threads") or torch.get_num_threads()
    return f"{platform.processor() or platform.machine()}, {threads} threads, torch {torch.__version__}"


def epochs_text(card: dict) -> str:
    planned = card["training"]["train"]["epochs"]
    done = card["epochs_trained"]
    return f"{done} of {planned} planned" if done < planned else f"{done}"


def base_card(
    args, run: dict, log: list[dict], config: dict, best: dict, test: dict, previous: dict | None
) -> dict:
    """The fields every model card has; ``test`` holds what the kind measured."""
    return run_fields(args.name, run, log, previous) | {
        "architecture": config,
        "best_epoch": int(best["epoch"]),
        "machine": machine(run),
        "test": test,
    }


def install(run: Path, filename: str, card: dict, markdown: str) -> None:
    """Copy the run's best weights into the package, with the card as JSON and markdown."""
    WEIGHTS.mkdir(parents=True, exist_ok=True)
    stem = Path(filename).stem
    shutil.copyfile(run / "best.safetensors", WEIGHTS / filename)
    (WEIGHTS / f"{stem}.json").write_text(json.dumps(card, indent=2) + "\n")
    (WEIGHTS / f"{stem}.md").write_text(markdown)
    print(f"wrote {WEIGHTS / filename} and its model card")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("run", type=Path)
    parser.add_argument("name")
    parser.add_argument("--data", required=True)
    parser.add_argument("--pairs", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--kind",
        choices=["masknet", "denoise", "pointnetlk", "dcp", "prnet", "pcrnet", "rpmnet"],
        default="masknet",
    )
    parser.add_argument("--previous", type=Path, help="card (.json) of the --init weights")
    parser.add_argument(
        "--previous-run", type=Path, help="run folder of the --init weights, when they have no card"
    )
    args = parser.parse_args()
    previous = json.loads(args.previous.read_text()) if args.previous else None
    if args.previous_run:
        previous = run_summary(args.previous_run)
    if args.kind not in ("masknet", "denoise"):
        from ship_network import ship_network

        return ship_network(args, previous)
    if args.kind == "denoise":
        from ship_denoise import ship_denoise

        return ship_denoise(args, previous)

    run, log = read_run(args.run)
    model = MaskNet.from_file(args.run / "best.safetensors")
    best = max(log, key=lambda row: float(row["val_precision"]))
    test = load_modelnet40(args.data, "test")
    pair_config = PairConfig(**run["task"]["pairs"])
    evaluations = {}
    for subset in ("all", "seen", "unseen"):
        points = test.subset(subset).points
        evaluations[subset] = evaluate_masknet(model, points, args.pairs, args.seed, pair_config)
        print(subset, format_table(evaluations[subset].rows), sep="\n")

    test_results = {subset: ev.to_dict() for subset, ev in evaluations.items()}
    card = base_card(args, run, log, model.config, best, test_results, previous)
    install(args.run, f"masknet_{args.name}.safetensors", card, render_card(card))


def previous_text(card: dict, depth: int = 0) -> str:
    """The training of the weights this run started from, one nested line per earlier run."""
    prev = card.get("previous")
    if not prev:
        return ""
    val_key = next(k for k in prev["log"][-1] if k.startswith("val_") and "loss" not in k)
    pick = min if "error" in val_key else max  # errors: lower is better; precision: higher
    task = prev["training"]["task"]
    loss = f", {task['loss'].upper()} loss" if task.get("loss") else ""
    lead = "**Started from**" if depth == 0 else "which started from"
    text = (
        f"{'  ' * depth}- {lead} `{prev['name']}` weights (`masknet train --init`): "
        f"{prev['epochs_trained']} epochs, {prev['training_minutes']:.0f} minutes, "
        f"{task['num_points']} points per training pair, keep ratio "
        f"{task['pairs']['keep_ratio']}{loss}; best {val_key} "
        f"{pick(float(r[val_key]) for r in prev['log']):.4f} on their own validation split.\n"
    )
    return text + previous_text(prev, depth + 1)


def resolution_note(num_points: int) -> str:
    """Validation and test pairs use the data's stored 1,024 points, whatever the training size."""
    if num_points == 1024:
        return ""
    return (
        " (validation and test pairs: all 1,024 stored points; MaskNet's per-point features do"
        " not depend on the cloud's density and its max-pooled source feature barely does, so"
        " the weights carry over)"
    )


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
  {pairs["noise_sigma"]}, outliers {pairs["outlier_ratio"]}; {task["num_points"]} template points per training
  pair{resolution_note(task["num_points"])}.
- Optimiser: Adam, lr {train["lr"]} ({train["lr_schedule"]} schedule, min {train["min_lr"]}), batch
  {train["batch_size"]}, {task["loss"].upper()} loss, {train["precision"]} autocast, seed {train["seed"]}.
- Epochs: {epochs_text(card)} (best validation epoch {card["best_epoch"]}, the one shipped),
  {card["training_minutes"]:.0f} minutes on {card["machine"]}.
{previous_text(card)}
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

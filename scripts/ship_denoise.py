"""Ship denoising MaskNet weights with a measured model card (ship_weights.py --kind denoise).

Outlier removal is measured on seeded ModelNet40 test pairs at 5, 10 and 20% uniform
outliers, threshold 0.5, beside Open3D's statistical and radius outlier removal.
"""

from __future__ import annotations

import numpy as np
from ship_weights import base_card, epochs_text, install, previous_text, read_run

from masknet.data import PairConfig, load_modelnet40, make_test_pairs
from masknet.denoising import open3d_radius_outlier_removal, open3d_statistical_outlier_removal
from masknet.evaluation.metrics import outlier_removal_metrics
from masknet.models import MaskNet


def ship_denoise(args, previous: dict | None) -> None:
    run, log = read_run(args.run)
    model = MaskNet.from_file(args.run / "best.safetensors")
    test = load_modelnet40(args.data, "test").points
    base = run["task"]["pairs"]
    results = {}
    for ratio in (0.05, 0.1, 0.2):
        pairs = make_test_pairs(
            test, args.pairs, PairConfig(**(base | {"outlier_ratio": ratio})), args.seed
        )
        noisy, real = pairs.source.numpy(), pairs.source_mask.numpy()
        scores = model.predict(noisy, pairs.template.numpy(), precision="fp32", normalize=False)
        results[f"{ratio:.0%}"] = {
            "MaskNet (threshold 0.5)": outlier_removal_metrics(scores >= 0.5, real),
            "Open3D statistical (20, 2.0)": outlier_removal_metrics(
                np.stack([open3d_statistical_outlier_removal(c) for c in noisy]), real
            ),
            "Open3D radius (8, 0.1)": outlier_removal_metrics(
                np.stack([open3d_radius_outlier_removal(c) for c in noisy]), real
            ),
        }
        print(ratio, results[f"{ratio:.0%}"])
    best = max(log, key=lambda row: float(row["val_f1"]))
    test = {"pairs": args.pairs, "seed": args.seed, "results": results}
    card = base_card(args, run, log, model.config, best, test, previous)
    install(args.run, f"masknet_{args.name}.safetensors", card, render(card))


def render(card: dict) -> str:
    train, task = card["training"]["train"], card["training"]["task"]
    pairs = task["pairs"]
    rows = [
        f"| {ratio} | {method} | {m['outlier_precision']:.4f} | {m['outlier_recall']:.4f} "
        f"| {m['inliers_kept']:.4f} |"
        for ratio, methods in card["test"]["results"].items()
        for method, m in methods.items()
    ]
    curve = "\n".join(
        f"| {r['epoch']} | {float(r['lr']):.2e} | {float(r['train_f1']):.4f} | {float(r['val_precision']):.4f} "
        f"| {float(r['val_recall']):.4f} | {float(r['val_f1']):.4f} | {float(r['epoch_min']):.1f} |"
        for r in card["log"]
    )
    return f"""# Model card: `masknet_{card["name"]}`

MaskNet applied the other way round (the paper's denoising use): it scores the points of a
noisy source cloud given a clean template of the same object. Same architecture as
`masknet_modelnet40`. Load it with `MaskNet.pretrained("{card["name"]}")`, or use
`masknet.denoise(noisy, template)` / `masknet denoise NOISY TEMPLATE -o OUT`.

## Training actually done
- `masknet train --model denoise`: ModelNet40 training split, {card["training"]["shapes"]["train"]} shapes
  ({card["training"]["shapes"]["val"]} held out for validation).
- Pairs: source with {pairs["keep_ratio"]:.0%} of the template's points plus **{pairs["outlier_ratio"]:.0%}
  uniform outliers** in its bounding box, rotation <= {pairs["max_angle_deg"]} deg, translation in
  [-{pairs["max_translation"]}, {pairs["max_translation"]}]^3. Target: 1 for real source points, 0 for outliers.
- Adam, lr {train["lr"]} ({train["lr_schedule"]}), batch {train["batch_size"]}, {task["loss"].upper()} loss,
  {train["precision"]} autocast, seed {train["seed"]}.
- Epochs: {epochs_text(card)} (best validation F1 at epoch {card["best_epoch"]}, shipped),
  {card["training_minutes"]:.0f} minutes on {card["machine"]}.
{previous_text(card)}
## Outlier removal on test pairs
{card["test"]["pairs"]} seeded ModelNet40 **test** pairs per outlier rate (seed {card["test"]["seed"]}), the
training protocol otherwise. Outlier precision: removed points that were outliers; outlier recall:
outliers removed; inliers kept: real points kept. Open3D's filters need no template.

| outliers | method | outlier precision | outlier recall | inliers kept |
|---|---|---|---|---|
{chr(10).join(rows)}

## Training curve
| epoch | lr | train F1 | val precision | val recall | val F1 | minutes |
|---|---|---|---|---|---|---|
{curve}

## Limits
Trained on synthetic unit-radius CAD shapes with uniform outliers; the template must be roughly
aligned with the noisy cloud (within the training range).
"""

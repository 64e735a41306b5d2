"""The markdown model card of shipped CrossMaskNet weights (``crossmasknet_<name>``).

The card's fields come from :mod:`masknet.cards` (the run folder) and from
``scripts/ship.py crossmasknet`` (storage check, test metrics, inference time).
"""

from __future__ import annotations

from masknet.cards import epochs_text, previous_text

__all__ = ["render_crossmasknet_card", "training_steps"]


def training_steps(card: dict) -> int:
    """Optimiser steps of the epochs logged: each epoch drops its last partial batch, so it
    has (training shapes // batch size) steps."""
    train = card["training"]["train"]
    return card["epochs_trained"] * (card["training"]["shapes"]["train"] // train["batch_size"])


def _test_rows(card: dict) -> str:
    """The test table's rows: each selection rule's precision, recall, F1 and IoU."""
    result = card["test"]["all"]
    return "\n".join(
        f"| {rule} | {m['precision']:.4f} | {m['recall']:.4f} | {m['f1']:.4f} | {m['iou']:.4f} |"
        for rule, m in result["metrics"].items()
    )


def _storage_text(card: dict) -> str:
    """Which dtype the file stores, and the label agreement that chose it."""
    storage = card["storage"]
    agreement = 100 * storage["fp16_point_agreement"]
    rule = (
        f"fp16 weights (loaded into the fp32 network) give the same top-k label as the fp32 "
        f"weights for {agreement:.2f}% of template points on the {storage['pairs']:,} test pairs "
        f"(fp16 is used from {100 * storage['min_agreement']:.1f}%)"
    )
    return f"Stored in **{storage['dtype']}**: {rule}. The test metrics are the stored weights'."


def _speed_text(card: dict) -> str:
    """The inference times at batch 1 beside the paper's MaskNet, timed in the same run."""
    speed = card["speed"]
    rows = "\n".join(
        f"| {points} | {ms['this']:.1f} | {ms['paper']:.1f} | {ms['this'] / ms['paper']:.2f} |"
        for points, ms in speed["ms"].items()
    )
    return f"""## Inference time
One pair at a time (the template's points, a source of 70% of them), fp32, median of
{speed["repeats"]} calls of `predict_mask` after a warm-up (FPFH inputs included),
{speed["threads"]} torch threads, {speed["machine"]}; the paper's MaskNet
(`masknet_modelnet40`) timed in the same run.

| template points | CrossMaskNet, ms | the paper's MaskNet, ms | time ratio |
|---|---|---|---|
{rows}

"""


def render_crossmasknet_card(card: dict) -> str:
    """The markdown model card of CrossMaskNet weights."""
    train, task = card["training"]["train"], card["training"]["task"]
    pairs = task["pairs"]
    arch = card["architecture"]
    result = card["test"]["all"]
    topk = result["metrics"]["top-k (k=M)"]["precision"]
    curve = "\n".join(
        f"| {r['epoch']} | {float(r['lr']):.2e} | {float(r['train_loss']):.4f} "
        f"| {float(r['train_precision']):.4f} | {float(r['val_loss']):.4f} "
        f"| {float(r['val_precision']):.4f} | {float(r['epoch_min']):.1f} |"
        for r in card["log"]
    )
    version = f" v{card['version']}" if card.get("version") else ""
    return f"""# Model card: `crossmasknet_{card["name"]}`{version}

CrossMaskNet (`masknet.models.cross_masknet`): MaskNet's job (which template points the
partial source sees) from EdgeConv features over each point's {arch["k"]} nearest points,
{arch["layers"]} steps of attention between the clouds and MaskNet's head, with each point's
FPFH descriptor and its distance to the nearest descriptor of the other cloud as inputs
(`descriptors={arch.get("descriptors")!r}`). Trained by `masknet train --model crossmasknet`
in this repository. Load it with `CrossMaskNet.pretrained("{card["name"]}")`
(`--weights crossmasknet_{card["name"]}` on the command line). It is the default mask of
one round of Mask-X (`masknet.register(..., method="icp" | "pointnetlk" | "dcp" | "prnet" |
"pcrnet" | "rpmnet")`).

## Training actually done
- Data: ModelNet40 training split, **{train["extra"].get("categories", "all")}** categories;
  {card["training"]["shapes"]["train"]} shapes for training and {card["training"]["shapes"]["val"]}
  held out of the *training* split for validation ({train["val_pairs"]} pairs).
- Pairs (fresh every epoch, seeded): protocol `{pairs["protocol"]}`, keep ratio {pairs["keep_ratio"]}
  (random views), rotation <= {pairs["max_angle_deg"]} deg about a random axis, translation uniform
  in [-{pairs["max_translation"]}, {pairs["max_translation"]}]^3, noise sigma {pairs["noise_sigma"]},
  outliers {pairs["outlier_ratio"]}; {task["num_points"]} template points per pair.
- Optimiser: Adam, lr {train["lr"]} ({train["lr_schedule"]} schedule, min {train["min_lr"]}), batch
  {train["batch_size"]}, {task["loss"].upper()} loss, {train["precision"]}, seed {train["seed"]}.
- Epochs: {epochs_text(card)} ({training_steps(card):,} optimiser steps; best validation epoch
  {card["best_epoch"]}, the one shipped), {card["training_minutes"]:.0f} minutes of wall time on
  {card["machine"]} (CPU time was not logged).
{previous_text(card)}
## Test metrics
{result["pairs"]:,} seeded pairs (seed {result["seed"]}) from the ModelNet40 **test** split, the
training protocol, fp32 inference. Top-k uses k = M (number of source points); random top-k
is the chance baseline. Top-k precision {topk:.4f} ± {result["topk_precision_stderr"]:.4f}
(standard error over pairs).

| selection | precision | recall | F1 | IoU |
|---|---|---|---|---|
{_test_rows(card)}

## Storage
{_storage_text(card)}

{_speed_text(card)}## Training curve
| epoch | lr | train loss | train precision | val loss | val precision | minutes |
|---|---|---|---|---|---|---|
{curve}

## Limits
Trained on clean, synthetic, unit-radius CAD samples with {100 * (1 - pairs["keep_ratio"]):.0f}% of
the points missing and rotations up to {pairs["max_angle_deg"]} degrees. Expect lower precision on
real sensor data, other missing ratios, larger rotations, noise and outliers. Its FPFH inputs are
computed on the CPU for every call (Open3D's; without Open3D the same numbers by numpy).
"""

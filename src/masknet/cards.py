"""Model cards: the fields of a card from a training run folder, and its markdown.

A card is a dict (saved as JSON beside the weights) holding what the run folder says
(``run.json``, ``log.csv``) and what was measured on test pairs; the ``render_*``
functions turn it into the markdown card shipped in ``resources/weights/``. The
measuring and installing is ``scripts/ship.py``.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import torch

from masknet.models import REGISTRATION_NETWORKS

__all__ = [
    "DESCRIPTIONS",
    "base_card",
    "epochs_text",
    "machine",
    "previous_text",
    "read_run",
    "render_denoise_card",
    "render_masknet_card",
    "render_network_card",
    "run_fields",
    "run_summary",
]


# What each network is, for the card (the sizes come from the weights' config).
DESCRIPTIONS = {
    "pointnetlk": "PointNetLK (Aoki et al., CVPR 2019): a PointNet encoder without BatchNorm and "
    "max pooling, inverse-compositional Lucas-Kanade on SE(3) with a finite-difference Jacobian.",
    "dcp": "DCP-v2 (Wang & Solomon, ICCV 2019): a DGCNN embedding (LayerNorm for BatchNorm), one "
    "layer of cross-cloud attention, soft correspondences and a differentiable SVD.",
    "prnet": "PRNet (Wang & Solomon, NeurIPS 2019): DGCNN and attention as DCP, keypoints by "
    "feature norm, Gumbel-softmax correspondences with a learned temperature, SVD, iterated; "
    "without the cycle-consistency and feature-alignment losses.",
    "pcrnet": "Iterative PCRNet (Sarode et al., 2019): a PointNet global feature per cloud "
    "(no BatchNorm), fully connected layers regressing a quaternion and a translation, iterated.",
    "rpmnet": "RPM-Net (Yew & Lee, CVPR 2020): features from [x_i, x_j - x_i, PPF] over k nearest "
    "neighbours (PCA normals, sign-free PPF), learned annealing parameters, Sinkhorn with slack, "
    "weighted SVD, iterated.",
}


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
    from masknet.runtime import cpu_name

    threads = run["train"].get("threads") or torch.get_num_threads()
    return f"{cpu_name()}, {threads} threads, torch {torch.__version__}"


def epochs_text(card: dict) -> str:
    """Epochs trained, "N of M planned" when the run stopped early."""
    planned = card["training"]["train"]["epochs"]
    done = card["epochs_trained"]
    return f"{done} of {planned} planned" if done < planned else f"{done}"


def base_card(
    name: str,
    run: dict,
    log: list[dict],
    config: dict,
    best: dict,
    test: dict,
    previous: dict | None,
) -> dict:
    """The fields every model card has: ``name`` (of the shipped weights), the run's
    ``run.json`` and log rows, the architecture ``config``, the ``best`` log row (the
    epoch shipped), ``test`` (what the kind measured) and the ``previous`` card."""
    return run_fields(name, run, log, previous) | {
        "architecture": config,
        "best_epoch": int(best["epoch"]),
        "machine": machine(run),
        "test": test,
    }


def previous_text(card: dict, depth: int = 0) -> str:
    """The training of the weights this run started from, one nested line per earlier run."""
    prev = card.get("previous")
    if not prev:
        return ""
    val_key = next(k for k in prev["log"][-1] if k.startswith("val_") and "loss" not in k)
    pick = min if "error" in val_key else max  # errors: lower is better; precision: higher
    lead = "**Started from**" if depth == 0 else "which started from"
    text = (
        f"{'  ' * depth}- {lead} `{prev['name']}` weights (`masknet train --init`): "
        f"{prev['epochs_trained']} epoch{'s' if prev['epochs_trained'] != 1 else ''}, "
        f"{prev['training_minutes']:.0f} minutes, {training_text(prev['training']['task'])}; best {val_key} "
        f"{pick(float(r[val_key]) for r in prev['log']):.4f} on their own validation split.\n"
    )
    return text + previous_text(prev, depth + 1)


# Tasks whose loss is fixed by the task (BCE on their masks), whatever ``loss`` a run
# recorded: earlier runs recorded the command line's MaskNet default there.
BCE_TASKS = {"masknet2": "BCE on the source scores", "refinemask": "BCE on both masks"}


def training_text(task: dict) -> str:
    """The points, keep ratio and loss a task (a card's ``training.task``) trained with."""
    points = f"{task['num_points']} points per ModelNet40 pair"
    if task.get("scans") and task.get("view"):
        points += f", {task['view']['template_points']}-point templates cut from scans"
    loss = BCE_TASKS.get(task.get("name", ""))
    if loss is None:
        loss = f"{task['loss'].upper()} loss" if task.get("loss") else ""
    return f"{points}, keep ratio {task['pairs']['keep_ratio']}" + (f", {loss}" if loss else "")


def resolution_note(num_points: int) -> str:
    """Validation and test pairs use the data's stored 1,024 points, whatever the training size."""
    if num_points == 1024:
        return ""
    return (
        " (validation and test pairs: all 1,024 stored points; MaskNet's per-point features do"
        " not depend on the cloud's density and its max-pooled source feature barely does, so"
        " the weights carry over)"
    )


def render_masknet_card(card: dict) -> str:
    """The markdown model card of MaskNet weights (``masknet_<name>``)."""
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
    version = f" v{card['version']}" if card.get("version") else ""
    limits = (
        "Trained on ModelNet40 CAD samples and crops of real scans, 30% missing. On pairs cut from\n"
        "real scans it is more precise than the ModelNet40-only weights, but still far from its\n"
        "ModelNet40 figure, and slightly below those weights on ModelNet40 itself."
        if "scans" in task
        else f"Trained on clean, synthetic, unit-radius CAD samples with {100 * (1 - pairs['keep_ratio']):.0f}% missing points.\n"
        "Expect lower precision on real sensor data, other missing ratios, larger rotations, noise and outliers."
    )
    arch = card["architecture"]
    paper = (
        "the paper's architecture"
        if (arch["encoder_channels"], arch["head_channels"]) == PAPER_CHANNELS
        else "the paper's design at a smaller size"
    )
    return f"""# Model card: `masknet_{card["name"]}`{version}

MaskNet (Sarode, Dhagat et al., 3DV 2020), {paper}
(encoder {arch["encoder_channels"]}, head {arch["head_channels"]}),
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
  {card["training_minutes"]:.0f} minutes on {card["machine"]}.{_note(card)}
{previous_text(card)}
## Test metrics
{card["test"]["all"]["pairs"]} seeded pairs (seed {card["test"]["all"]["seed"]}) per row group from the
ModelNet40 **test** split, same pair protocol as training, fp32 inference. Top-k uses k = M (number of source
points); random top-k is the chance baseline.

| test categories | selection | precision | recall | F1 | IoU |
|---|---|---|---|---|---|
{chr(10).join(rows)}

{scans_text(card)}{speed_text(card)}## Training curve
| epoch | lr | train loss | train precision | val precision | minutes |
|---|---|---|---|---|---|
{curve}

## Limits
{limits}
"""


PAPER_CHANNELS = ([64, 64, 64, 128, 1024], [1024, 512, 256, 128])


def speed_text(card: dict) -> str:
    """The card's inference times beside the paper's network, where measured."""
    speed = card.get("speed")
    if not speed:
        return ""
    rows = "\n".join(
        f"| {points} | {ms['this']:.1f} | {ms['paper']:.1f} | {ms['paper'] / ms['this']:.1f}x |"
        for points, ms in speed["ms"].items()
    )
    return f"""## Inference time
One pair (the template's points, a source of 70% of them), fp32, median of
{speed["repeats"]} calls of `predict_mask` after a warm-up, {speed["threads"]} torch threads,
{speed["machine"]}; beside the paper's network (`masknet_modelnet40`).

| template points | this network, ms | the paper's, ms | faster |
|---|---|---|---|
{rows}

"""


def scans_text(card: dict) -> str:
    """The real-scan part of a card trained with ``--scans`` (empty otherwise)."""
    task = card["training"]["task"]
    if "scans" not in task:
        return ""
    view = task["view"]
    lines = [
        "## Real scans",
        f"- Trained on {len(task['scans'])} scans as well ({', '.join(task['scans'])}); "
        f"{task['scan_batches']} batches of scan pairs per epoch beside ModelNet40 pairs on "
        f"{task['modelnet_fraction']:.0%} of the shapes ({task['modelnet_view_fraction']:.0%} of "
        f"those batches cut as sensor-like views). Scan pairs: {view['template_points']} template "
        f"points, keep ratio {view['keep_ratio']}, noise up to {view['noise_sigma']} of the crop radius.",
        f"- Held out whole for validation: {', '.join(task['val_scans'])}.",
        "",
        "Top-k precision on seeded pairs cut from scans (noise 0.002 of the crop radius, "
        f"{view['keep_ratio']} kept), fp32:",
        "",
        "| scans | pairs | top-k precision | recall | IoU | random top-k |",
        "|---|---|---|---|---|---|",
    ]
    for label, result in card.get("scans_test", {}).items():
        topk, rand = result["metrics"]["top-k (k=M)"], result["metrics"]["random top-k"]
        lines.append(
            f"| {label} ({len(result['scans'])}) | {result['pairs']} | {topk['precision']:.4f} "
            f"| {topk['recall']:.4f} | {topk['iou']:.4f} | {rand['precision']:.4f} |"
        )
    return "\n".join(lines) + "\n\n"


def render_denoise_card(card: dict) -> str:
    """The markdown model card of denoising MaskNet weights."""
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
    version = f" v{card['version']}" if card.get("version") else ""
    return f"""# Model card: `masknet_{card["name"]}`{version}

MaskNet applied the other way round (the paper's denoising use): it scores the points of a
noisy source cloud given a clean template of the same object. Same architecture as
`masknet_modelnet40`. Load it with `MaskNet.pretrained("{card["name"]}")`, or use
`masknet.denoise(template, noisy)` / `masknet denoise TEMPLATE NOISY -o OUT`.

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


def render_refine_card(card: dict) -> str:
    """The markdown model card of refinement-mask weights (:class:`RefineMaskNet`)."""
    train, task = card["training"]["train"], card["training"]["task"]
    residual = task["residual"]
    corruption = task["corruption"]
    test = card["test"]
    rows, curve = _refine_tables(card)
    version = f" v{card['version']}" if card.get("version") else ""
    scans = ", ".join(task.get("scans", [])) or "none"
    held = ", ".join(task.get("val_scans", [])) or "none"
    context = card.get("architecture", {}).get("context", 0)
    pooled = (
        f" and, from v1.1 on, a context stage: {context} channels of each point's neighbourhood "
        "(its features pooled over its k nearest points in its own cloud)"
        if context
        else ""
    )
    start = f"\n  --init refinemask_{card['name']}.safetensors" if task.get("init") else ""
    if task.get("init") and context:
        start += f" --model-config '{{\"context\": {context}}}'"
    return f"""# Model card: `refinemask_{card["name"]}`{version}

The refinement mask of the iterative loop (`masknet.models.refine.RefineMaskNet`,
{card["parameters"]:,} parameters): given a template and a source **already brought close by
registration, in one frame**, it predicts the template points the source covers and the source
points that lie on the template's object. Each point is described by its neighbours in its own
cloud and its nearest points in the other cloud (offsets in units of the clouds' spacings, their
lengths, and the ratio of the spacings), a point MLP and a max-pool per cloud{pooled}. Load it with
`RefineMaskNet.pretrained("{card["name"]}")`, or use it in `register(..., iterations=3,
refine_masks="learned")`.

## Training actually done
- Command: `masknet train --model refine --scans <scans_train> --epochs {train["epochs"]} --lr {train["lr"]}
  --lr-schedule {train["lr_schedule"]} --precision {train["precision"]} --val-pairs {train["val_pairs"]}
  --scan-points {task["view"]["template_points"]} --threads {train.get("threads")}{start}`
- Data, fresh every epoch and seeded: ModelNet40 training-split pairs (the paper's protocol,
  half of the batches cut as sensor-like views sampled apart from their templates), and
  {task["scan_batches"]} batches per epoch of views cut from {len(task.get("scans", []))} real
  scans ({scans}). Held out whole for validation: {held}.
- Every source corrupted as the two-sided network's: uniform outliers of 0–{corruption["max_outlier_ratio"]:.0%}
  of the source, Gaussian noise up to {corruption["max_noise"]} of the radius, and with
  probability {corruption["clutter_probability"]} clutter from another cloud.
- Then each source is moved onto its template by the true pose and off it by a **residual
  pose** (`masknet.data.residuals.ResidualConfig`): {residual["near_fraction"]:.0%} of pairs turned by up to
  {residual["near_deg"]}°, {residual["wide_fraction"]:.0%} by up to {residual["max_deg"]}°, the rest half-normal with
  scale {residual["scale_deg"]}°; translations half-normal with scale {residual["translation"]} +
  {residual["translation_per_deg"]} per degree of radius: wider than what one round of Mask-ICP
  leaves (round 1 of "Masks per round" in docs/RESULTS.md).
- Loss: BCE on both masks. Adam, lr {train["lr"]} ({train["lr_schedule"]}), batch {train["batch_size"]},
  {train["precision"]}, seed {train["seed"]}.
- Epochs: {epochs_text(card)} (best validation score at epoch {card["best_epoch"]}, shipped),
  {card["training_minutes"]:.0f} minutes on {card["machine"]}.{_note(card)}
{previous_text(card)}
## Against the nearest-neighbour rule
{test["pairs"]} seeded ModelNet40 **test** pairs per ModelNet40 set and {test["pairs_per_scan"]} pairs per scan of
the evaluation scans (never trained on; 70% views of 4,096-point templates, noise 0.2% of the
radius), seed {test["seed"]}. Each source is moved onto its template by the true pose and turned by
the residual about its centroid. Template masks of both: top-k with k = the source points kept.
Measured by `scripts/ship.py refine` (the same table as `masknet benchmark refine-masks`).

| set | residual (deg) | precision, rule | precision, learned | recall, rule | recall, learned | real kept, rule | real kept, learned | outliers removed, rule | outliers removed, learned |
|---|---|---|---|---|---|---|---|---|---|
{rows}

## Training curve
Validation at score 0.5: template precision (all, and scan pairs), source F1, share of
corrupted source points rejected; score = mean of template precision and source F1.

| epoch | lr | train loss | val template precision | val scans template precision | val source F1 | val outliers removed | val score | minutes |
|---|---|---|---|---|---|---|---|---|
{curve}

## Limits
Trained on pairs within about 45° of each other; on a pair far from aligned it cannot say
more than the clouds' local shapes do. It is a refinement stage: round 1 of the loop still
needs another mask (MaskNet or the two-sided network).
"""


def _refine_tables(card: dict) -> tuple[str, str]:
    """The refinement card's table rows: against the rule (per set), and the training curve."""
    rows = "\n".join(
        f"| {r['set']} | {r['residual_deg']:g} | {r['rule_precision']:.3f} | "
        f"{r['learned_precision']:.3f} | {r['rule_recall']:.3f} | {r['learned_recall']:.3f} | "
        f"{r['rule_real_kept']:.3f} | {r['learned_real_kept']:.3f} | "
        f"{_maybe(r['rule_outliers_removed'])} | {_maybe(r['learned_outliers_removed'])} |"
        for r in card["test"]["rows"]
    )
    curve = "\n".join(
        f"| {r['epoch']} | {float(r['lr']):.2e} | {float(r['train_loss']):.4f} | "
        f"{float(r['val_template_precision']):.4f} | {float(r['val_scans_template_precision']):.4f} | "
        f"{float(r['val_source_f1']):.4f} | {float(r['val_outliers_removed']):.3f} | "
        f"{float(r['val_score']):.4f} | {float(r['epoch_min']):.1f} |"
        for r in card["log"]
    )
    return rows, curve


def _note(card: dict) -> str:
    """The card's ``note`` (what the run folder cannot tell, e.g. a resumed schedule)."""
    return f"\n- {card['note']}" if card.get("note") else ""


def _maybe(value: float) -> str:
    return "–" if value != value else f"{value:.3f}"


def render_network_card(card: dict, method: str) -> str:
    """The markdown model card of a registration network's weights (``method``: its name)."""
    train, task = card["training"]["train"], card["training"]["task"]
    cls = REGISTRATION_NETWORKS[method]
    rows = []
    for protocol, methods in card["test"]["results"].items():
        for network, e in methods.items():
            rows.append(
                f"| {protocol} | {network} | {e['rot_mean']:.2f} | {e['rot_median']:.2f} "
                f"| {e['rot_rmse']:.2f} | {e['trans_mean']:.4f} | {e['trans_median']:.4f} |"
            )
    curve = "\n".join(
        f"| {r['epoch']} | {float(r['lr']):.2e} | {float(r['train_rotation_error_deg']):.3f} "
        f"| {float(r['val_rotation_error_deg']):.3f} | {float(r['epoch_min']):.1f} |"
        for r in card["log"]
    )
    pairs = task["pairs"]
    iterations = cls.default_iterations
    started = previous_text(card)
    if started:
        started += "  The untrained row is the seeded random start of the first run.\n"
    return f"""# Model card: `{cls.weights_prefix}{card["name"]}`

{DESCRIPTIONS[method]} Implemented in `masknet.models.{cls.__name__}`; load it with
`{cls.__name__}.pretrained("{card["name"]}")`, or use `masknet.register(..., method="{method}")`.

Architecture (the keyword arguments of `{cls.__name__}`): `{card["architecture"]}`.
These are smaller than the paper's, to fit a 2-core CPU budget; a smaller model trained honestly
is the aim, not the paper's numbers.

## Training actually done
- `masknet train --model {method}`: ModelNet40 training split (all categories),
  {card["training"]["shapes"]["train"]} shapes for training, {card["training"]["shapes"]["val"]} held out for validation.
- Pairs: keep ratio {pairs["keep_ratio"]} (1.0 = full clouds), rotation <= {pairs["max_angle_deg"]} deg,
  translation in [-{pairs["max_translation"]}, {pairs["max_translation"]}]^3, {task["num_points"]} template points per pair,
  {task["iterations"]} iteration(s) per training pair, gradients through every iteration.
- Loss: ||T_est T_gt^-1 - I||_F^2 + {task.get("auxiliary_weight", task.get("feature_weight"))} x the network's auxiliary loss (if it has one).
- Adam, lr {train["lr"]} ({train["lr_schedule"]}), batch {train["batch_size"]}, fp32, seed {train["seed"]}.
- Epochs: {epochs_text(card)} (best validation epoch {card["best_epoch"]}, shipped),
  {card["training_minutes"]:.0f} minutes on {card["machine"]}, sharing the 2 cores with another training run.
{started}
## Test errors
{card["test"]["pairs"]} seeded ModelNet40 **test** pairs per protocol (seed {card["test"]["seed"]}), {iterations} iteration(s),
1,024-point templates; rotation errors in degrees, translations in units of the unit-radius shapes.
"untrained" is this architecture at the seeded weights training started from; "identity" is no
motion at all; Mask-X uses the shipped MaskNet's mask.

| pairs | network | rot mean | rot median | rot RMSE | trans mean | trans median |
|---|---|---|---|---|---|---|
{chr(10).join(rows)}

## Training curve
| epoch | lr | train rot error (deg) | val rot error (deg) | minutes |
|---|---|---|---|---|
{curve}

## Limits
Trained for minutes on a CPU, where the papers train for hundreds of epochs on GPUs: expect
errors well above the papers'. Synthetic ModelNet40 pairs only; no noise in training.
"""

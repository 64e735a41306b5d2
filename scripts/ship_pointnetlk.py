"""Ship PointNetLK weights with a measured model card (called by ship_weights.py --kind pointnetlk).

The card sets the trained network beside the same architecture at its starting
(untrained, seeded) weights and beside identity (no motion), on seeded ModelNet40
test pairs: full clouds (the training protocol) and 30%-missing sources.
"""

from __future__ import annotations

import numpy as np
import torch
from ship_weights import base_card, epochs_text, install, read_run

from masknet.data import PairConfig, load_modelnet40, make_test_pairs
from masknet.evaluation.registration import pose_errors, summarize_errors
from masknet.models import PointNetLK
from masknet.registration import register


def _errors(network: PointNetLK | None, pairs, batch: int = 100) -> dict[str, float]:
    truth = pairs.transform.double().numpy()
    if network is None:  # identity: no motion at all
        return summarize_errors(*pose_errors(np.broadcast_to(np.eye(4), truth.shape).copy(), truth))
    estimates = []
    for i in range(0, len(truth), batch):
        result = register(
            pairs.template[i : i + batch].numpy(),
            pairs.source[i : i + batch].numpy(),
            method="pointnetlk",
            use_mask=False,
            network=network,
        )
        estimates.append(result.transform)
    return summarize_errors(*pose_errors(np.concatenate(estimates), truth))


def ship_pointnetlk(args, previous: dict | None) -> None:
    run, log = read_run(args.run)
    trained = PointNetLK.from_file(args.run / "best.safetensors")
    torch.manual_seed(run["train"]["seed"])  # the loop's seeding: the starting weights
    untrained = PointNetLK(**trained.config).eval()
    test = load_modelnet40(args.data, "test").points
    protocols = {
        "full clouds (training protocol)": PairConfig(**run["task"]["pairs"]),
        "30% missing (default protocol)": PairConfig(),
    }
    results = {}
    for label, config in protocols.items():
        pairs = make_test_pairs(test, args.pairs, config, args.seed)
        results[label] = {
            "trained": _errors(trained, pairs),
            "untrained (starting weights)": _errors(untrained, pairs),
            "identity (no motion)": _errors(None, pairs),
        }
        print(label, results[label])
    best = min(log, key=lambda row: float(row["val_rotation_error_deg"]))
    test = {"pairs": args.pairs, "seed": args.seed, "results": results}
    card = base_card(args, run, log, trained.config, best, test, previous)
    install(args.run, f"pointnetlk_{args.name}.safetensors", card, render(card))


def render(card: dict) -> str:
    train, task = card["training"]["train"], card["training"]["task"]
    arch = card["architecture"]
    rows = []
    for protocol, methods in card["test"]["results"].items():
        for method, e in methods.items():
            rows.append(
                f"| {protocol} | {method} | {e['rot_mean']:.2f} | {e['rot_median']:.2f} "
                f"| {e['rot_rmse']:.2f} | {e['trans_mean']:.4f} | {e['trans_median']:.4f} |"
            )
    curve = "\n".join(
        f"| {r['epoch']} | {float(r['lr']):.2e} | {float(r['train_rotation_error_deg']):.3f} "
        f"| {float(r['val_rotation_error_deg']):.3f} | {float(r['epoch_min']):.1f} |"
        for r in card["log"]
    )
    pairs = task["pairs"]
    return f"""# Model card: `pointnetlk_{card["name"]}`

PointNetLK (Aoki et al., CVPR 2019) as implemented in `masknet.models.PointNetLK`: a PointNet
encoder {arch["encoder_channels"]} **without BatchNorm** (so a cloud's features depend on that cloud
alone) and max pooling, inverse-compositional Lucas-Kanade on SE(3) with a finite-difference
Jacobian (step {arch["delta"]}), both clouds centred first. The feature size is
{arch["encoder_channels"][-1]}, smaller than the paper's 1,024, to fit the CPU budget: at K = 1,024 a
training step cost 4.4x more here. Load it with `PointNetLK.pretrained("{card["name"]}")`.

## Training actually done
- `masknet train --model pointnetlk`: ModelNet40 training split (all categories),
  {card["training"]["shapes"]["train"]} shapes for training, {card["training"]["shapes"]["val"]} held out for validation.
- Pairs as the paper trains PointNetLK: **full clouds** (keep ratio {pairs["keep_ratio"]}), rotation <=
  {pairs["max_angle_deg"]} deg, translation in [-{pairs["max_translation"]}, {pairs["max_translation"]}]^3,
  {task["num_points"]} points per cloud, {task["iterations"]} LK iterations per pair, gradients through every
  iteration and the Jacobian.
- Loss: ||T_est T_gt^-1 - I||_F^2 + {task["feature_weight"]} x ||feature residual||^2.
- Adam, lr {train["lr"]} ({train["lr_schedule"]}), batch {train["batch_size"]}, fp32, seed {train["seed"]}.
- Epochs: {epochs_text(card)} (best validation epoch {card["best_epoch"]}, shipped),
  {card["training_minutes"]:.0f} minutes on {card["machine"]}, sharing the 2 cores with another training run.

## Test errors
{card["test"]["pairs"]} seeded ModelNet40 **test** pairs per protocol (seed {card["test"]["seed"]}), 10 iterations,
1,024 points; rotation errors in degrees, translations in units of the unit-radius shapes.
"untrained" is this architecture at the seeded weights training started from: random PointNet
features already register clean full clouds well, so training matters less than one might expect.

| pairs | network | rot mean | rot median | rot RMSE | trans mean | trans median |
|---|---|---|---|---|---|---|
{chr(10).join(rows)}

## Training curve
| epoch | lr | train rot error (deg) | val rot error (deg) | minutes |
|---|---|---|---|---|
{curve}

## Limits
Trained on clean full clouds only. With a partial source (missing points) PointNetLK's global
feature no longer matches the template's; that is what MaskNet's mask (Mask-PointNetLK) repairs.
"""

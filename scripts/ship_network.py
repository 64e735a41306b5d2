"""Ship a registration network's weights with a measured model card
(called by ship_weights.py --kind pointnetlk|dcp|prnet|pcrnet|rpmnet).

The card sets the trained network beside the same architecture at its starting
(untrained, seeded) weights and beside identity (no motion), on seeded ModelNet40
test pairs: the network's training protocol and the default 30%-missing one, where
Mask-X (with the shipped MaskNet) is measured too.
"""

from __future__ import annotations

import numpy as np
import torch
from ship_weights import base_card, epochs_text, install, previous_text, read_run

from masknet.data import PairConfig, load_modelnet40, make_test_pairs
from masknet.evaluation.registration import pose_errors, summarize_errors
from masknet.models import REGISTRATION_NETWORKS
from masknet.registration import register

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


def _errors(method: str, network, pairs, use_mask: bool = False, batch: int = 100) -> dict:
    truth = pairs.transform.double().numpy()
    if network is None:  # identity: no motion at all
        return summarize_errors(*pose_errors(np.broadcast_to(np.eye(4), truth.shape).copy(), truth))
    estimates = []
    for i in range(0, len(truth), batch):
        result = register(
            pairs.template[i : i + batch].numpy(),
            pairs.source[i : i + batch].numpy(),
            method=method,
            use_mask=use_mask,
            network=network,
        )
        estimates.append(result.transform)
    return summarize_errors(*pose_errors(np.concatenate(estimates), truth))


def ship_network(args, previous: dict | None) -> None:
    method = args.kind
    cls = REGISTRATION_NETWORKS[method]
    run, log = read_run(args.run)
    trained = cls.from_file(args.run / "best.safetensors").eval()
    torch.manual_seed(run["train"]["seed"])  # the loop's seeding: the starting weights
    untrained = cls(**trained.config).eval()
    test = load_modelnet40(args.data, "test").points
    protocols = {
        f"training protocol (keep ratio {run['task']['pairs']['keep_ratio']})": PairConfig(
            **run["task"]["pairs"]
        ),
        "30% missing (default protocol)": PairConfig(),
    }
    results = {}
    for label, config in protocols.items():
        pairs = make_test_pairs(test, args.pairs, config, args.seed)
        results[label] = {
            "trained": _errors(method, trained, pairs),
            "untrained (starting weights)": _errors(method, untrained, pairs),
            "identity (no motion)": _errors(method, None, pairs),
        }
        if label.startswith("30%"):
            results[label]["trained, Mask-X"] = _errors(method, trained, pairs, use_mask=True)
        print(label, results[label], flush=True)
    best = min(log, key=lambda row: float(row["val_rotation_error_deg"]))
    test = {"pairs": args.pairs, "seed": args.seed, "results": results}
    card = base_card(args, run, log, trained.config, best, test, previous)
    install(args.run, f"{cls.weights_prefix}{args.name}.safetensors", card, render(card, method))


def render(card: dict, method: str) -> str:
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

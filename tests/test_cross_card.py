"""masknet.cross_card: the CrossMaskNet model card from a card's fields."""

from __future__ import annotations

import json

from masknet.cross_card import render_crossmasknet_card, training_steps
from masknet.models.weights import shipped_weights_path

CARD = shipped_weights_path("crossmasknet_modelnet40.json")


def test_steps_are_whole_batches_per_epoch():
    card = {
        "epochs_trained": 3,
        "training": {"train": {"batch_size": 32}, "shapes": {"train": 100}},
    }
    assert training_steps(card) == 9  # 100 // 32 = 3 full batches an epoch


def test_the_card_states_what_was_measured():
    card = json.loads(CARD.read_text())
    text = render_crossmasknet_card(card)
    assert text.startswith("# Model card: `crossmasknet_modelnet40`")
    stderr = card["test"]["all"]["topk_precision_stderr"]
    topk = card["test"]["all"]["metrics"]["top-k (k=M)"]["precision"]
    assert f"{topk:.4f} ± {stderr:.4f}" in text
    assert f"Stored in **{card['storage']['dtype']}**" in text
    assert text.count("\n| ") - 3 == len(card["log"]) + len(card["test"]["all"]["metrics"]) + 2
    assert f"{training_steps(card):,} optimiser steps" in text

"""masknet.cards: the shipped cards' JSON renders as markdown model cards."""

from __future__ import annotations

import json

import pytest

from masknet import cards, cross_card
from masknet.models.weights import shipped_weights_path

CARDS = sorted(shipped_weights_path("").glob("*.json"))


@pytest.mark.parametrize("path", CARDS, ids=[p.stem for p in CARDS])
def test_shipped_cards_render(path):
    card = json.loads(path.read_text())
    if path.stem.startswith("masknet_"):
        text = cards.render_masknet_card(card)
    elif path.stem.startswith("refinemask_"):
        text = cards.render_refine_card(card)
        assert text == path.with_suffix(".md").read_text()  # the card shipped is this render
    elif path.stem.startswith("crossmasknet_"):
        text = cross_card.render_crossmasknet_card(card)
        assert text == path.with_suffix(".md").read_text()
    else:
        text = cards.render_network_card(card, path.stem.split("_")[0])
    assert text.startswith(f"# Model card: `{path.stem}`")
    assert "## Training actually done" in text and "## Training curve" in text
    assert cards.epochs_text(card).split()[0] == str(card["epochs_trained"])


def test_base_card_from_a_run(tmp_path):
    (tmp_path / "run.json").write_text(json.dumps({"train": {"threads": 2, "epochs": 3}}))
    (tmp_path / "log.csv").write_text("epoch,elapsed_min,val_precision\n1,0.5,0.8\n2,1.0,0.9\n")
    run, log = cards.read_run(tmp_path)
    card = cards.base_card("demo", run, log, {"k": 1}, log[1], {"pairs": 5}, previous=None)
    assert card["name"] == "demo" and card["epochs_trained"] == 2 and card["best_epoch"] == 2
    assert card["training_minutes"] == 1.0 and "2 threads" in card["machine"]
    assert cards.epochs_text(card) == "2 of 3 planned"


def test_a_previous_run_is_described_by_what_its_task_trained_with():
    pairs = {"keep_ratio": 0.7}
    refine = {"name": "refinemask", "num_points": 1024, "loss": "mse", "pairs": pairs}
    refine |= {"scans": ["a"], "view": {"template_points": 512}}
    text = cards.training_text(refine)
    assert "BCE on both masks" in text and "MSE" not in text  # the task fixes its loss
    assert "512-point templates cut from scans" in text
    masknet = {"name": "masknet", "num_points": 512, "loss": "mse", "pairs": pairs}
    assert (
        cards.training_text(masknet) == "512 points per ModelNet40 pair, keep ratio 0.7, MSE loss"
    )

"""masknet.training.checkpoint: model, optimiser and state back exactly; a bad file refused."""

from __future__ import annotations

import pytest
import torch

from masknet.errors import MaskNetError
from masknet.training.checkpoint import load_checkpoint, save_checkpoint


def _model_and_optimiser(seed: int):
    torch.manual_seed(seed)
    model = torch.nn.Linear(4, 2)
    optimiser = torch.optim.Adam(model.parameters(), 1e-2)
    return model, optimiser


def test_a_checkpoint_restores_the_model_the_optimiser_and_the_state(tmp_path):
    model, optimiser = _model_and_optimiser(0)
    model(torch.randn(8, 4)).sum().backward()
    optimiser.step()
    save_checkpoint(tmp_path / "c.safetensors", model, optimiser, {"epoch": 3, "best": 0.5})
    again, again_optimiser = _model_and_optimiser(1)
    state = load_checkpoint(tmp_path / "c.safetensors", again, again_optimiser)
    assert state == {"epoch": 3, "best": 0.5}
    for a, b in zip(model.parameters(), again.parameters(), strict=True):
        torch.testing.assert_close(a, b)
    step = again_optimiser.state_dict()["state"][0]
    torch.testing.assert_close(step["exp_avg"], optimiser.state_dict()["state"][0]["exp_avg"])


def test_a_file_that_does_not_fit_is_one_line(tmp_path):
    model, optimiser = _model_and_optimiser(0)
    save_checkpoint(tmp_path / "c.safetensors", model, optimiser, {})
    wider = torch.nn.Linear(5, 2)
    with pytest.raises(MaskNetError, match="cannot resume from it"):
        load_checkpoint(tmp_path / "c.safetensors", wider, torch.optim.Adam(wider.parameters()))
    (tmp_path / "junk.safetensors").write_bytes(b"not a checkpoint")
    with pytest.raises(MaskNetError, match="junk.safetensors"):
        load_checkpoint(tmp_path / "junk.safetensors", model, optimiser)

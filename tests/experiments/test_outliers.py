"""The outliers experiment's register -> denoise -> register round."""

from __future__ import annotations

import numpy as np
import pytest


def test_denoise_round_keeps_the_first_estimate_when_nothing_survives(monkeypatch):
    """A first registration far off leaves no source point near the template: the second
    round is skipped (and counted) instead of failing on an empty cloud."""
    import torch

    from masknet.data.pairs import Pairs
    from masknet.experiments import outliers

    rng = np.random.default_rng(0)
    template = rng.uniform(-1, 1, (2, 64, 3)).astype(np.float32)
    source = template[:, :40].copy()
    source[1] += 100.0  # the second pair's source is far from its template
    truth = np.tile(np.eye(4), (2, 1, 1))
    truth[1, :3, 3] = -100.0
    pairs = Pairs(
        torch.from_numpy(template),
        torch.from_numpy(source),
        torch.ones(2, 64, dtype=torch.bool),
        torch.from_numpy(truth).float(),
        torch.ones(2, 40, dtype=torch.bool),
    )
    calls = []

    class Identity:
        transform = np.eye(4)

    def fake_register(template, source, **kwargs):
        calls.append(len(source))
        return Identity()

    monkeypatch.setattr(outliers, "register", fake_register)
    row = outliers.register_denoise_register(pairs, {"method": "distance"}, {})
    assert row["second_pass_skipped"] == 1
    assert calls == [40, 40, 40]  # both first rounds, then only the first pair's second
    assert row["trans_mean"] == pytest.approx(50.0 * np.sqrt(3), rel=1e-4)

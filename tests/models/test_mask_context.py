"""masknet.models.mask_context: MaskNet's residual context head starts as the paper's
network, learns, and keeps the paper's paths honest."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from masknet.models import MaskNet
from masknet.training.loop import _load_init


@pytest.fixture(scope="module")
def paper() -> MaskNet:
    torch.manual_seed(0)
    return MaskNet(encoder_channels=(16, 16, 32), head_channels=(32, 16)).eval()


def _widened(paper: MaskNet) -> MaskNet:
    net = MaskNet(encoder_channels=(16, 16, 32), head_channels=(32, 16), context=8)
    _load_init(net, paper)  # every paper tensor fits; only context.* is new
    return net.eval()


def test_a_widened_network_starts_as_the_paper_network(paper):
    net = _widened(paper)
    assert net.config["context"] == 8 and "context" not in paper.config
    template, source = torch.randn(2, 64, 3), torch.randn(2, 40, 3)
    with torch.no_grad():
        torch.testing.assert_close(net(template, source), paper(template, source))
    np.testing.assert_allclose(
        net.predict(template.numpy(), source.numpy(), precision="fp32"),
        paper.predict(template.numpy(), source.numpy(), precision="fp32"),
        atol=1e-5,
    )


def test_the_context_head_learns_and_changes_the_scores(paper):
    net = _widened(paper).train()
    template, source = torch.randn(4, 64, 3), torch.randn(4, 40, 3)
    target = (template[..., 0] > 0).float()  # a rule a point-wise head alone cannot see here
    optimiser = torch.optim.Adam(net.context.parameters(), 1e-2)
    for _ in range(5):
        loss = torch.nn.functional.binary_cross_entropy_with_logits(
            net(template, source, logits=True), target
        )
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    assert net.context.out[-1].weight.abs().sum() > 0  # the zero start moved
    with torch.no_grad():
        assert not torch.allclose(net.eval()(template, source), paper(template, source))


def test_the_paper_only_paths_refuse_a_network_with_context(paper):
    net = _widened(paper)
    with pytest.raises(ValueError, match="context"):
        net.fused()
    with pytest.raises(ValueError, match="context"):
        net.forward_reference(torch.randn(1, 8, 3), torch.randn(1, 8, 3))


def test_the_weights_file_rebuilds_the_context(paper, tmp_path):
    net = _widened(paper)
    torch.nn.init.normal_(net.context.out[-1].weight)
    net.save(tmp_path / "ctx.safetensors")
    again = MaskNet.from_file(tmp_path / "ctx.safetensors").eval()
    assert again.context is not None and again.context.k == 8
    template, source = torch.randn(1, 32, 3), torch.randn(1, 20, 3)
    with torch.no_grad():
        torch.testing.assert_close(again(template, source), net(template, source))

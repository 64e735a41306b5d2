"""PointNetLK: shapes, the Jacobian, recovery of a known transform, masks, weights."""

from __future__ import annotations

import math

import pytest
import torch

from masknet import MaskNetError
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.geometry import rotation_error_deg, se3_exp, transform_points
from masknet.models import PointNetLK

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def network() -> PointNetLK:
    """Untrained features already register full clouds (as measured); small for speed."""
    torch.manual_seed(0)
    return PointNetLK(encoder_channels=(64, 64, 64, 128, 256)).eval()


@pytest.fixture(scope="module")
def full_pairs():
    shapes = load_modelnet40(bundled_sample_path()).points[:4]
    config = PairConfig(keep_ratio=1.0, max_angle_deg=30, max_translation=0.5)
    return make_test_pairs(shapes, 4, config, seed=2)


def test_features_and_jacobian_shapes(network, full_pairs):
    f = network.features(full_pairs.template)
    assert f.shape == (4, 256)
    f0, jac = network.jacobian(full_pairs.template)
    assert jac.shape == (4, 256, 6)
    torch.testing.assert_close(f0, f)


def test_jacobian_matches_a_finite_difference_along_a_twist(network, full_pairs):
    tpl = full_pairs.template[:1].double()
    net = PointNetLK(encoder_channels=(64, 64, 64, 128, 256), delta=1e-4).double()
    net.load_state_dict(network.state_dict())
    f0, jac = net.jacobian(tpl)
    xi = torch.tensor([[0.3, -0.2, 0.1, 0.5, 0.2, -0.4]], dtype=torch.float64) * 1e-4
    moved = net.features(transform_points(se3_exp(xi), tpl))
    predicted = f0 + (jac @ xi[..., None])[..., 0]
    assert (moved - predicted).abs().max() < 1e-2 * (moved - f0).abs().max()


def test_recovers_a_known_transform_on_full_clouds(network, full_pairs):
    with torch.no_grad():
        solution = network(full_pairs.template, full_pairs.source, max_iterations=20)
    error = rotation_error_deg(
        solution.transform[:, :3, :3].double(), full_pairs.transform[:, :3, :3].double()
    )
    assert error.max() < 0.5, error
    t_error = (solution.transform[:, :3, 3] - full_pairs.transform[:, :3, 3]).norm(dim=-1)
    assert t_error.max() < 0.01
    assert solution.transform.shape == (4, 4, 4) and solution.iterations.max() <= 20


def test_masked_points_do_not_take_part(network, full_pairs):
    tpl, src = full_pairs.template[:2], full_pairs.source[:2]
    junk = torch.rand(2, 100, 3) * 5
    valid = torch.cat(
        [torch.ones(2, 1024, dtype=torch.bool), torch.zeros(2, 100, dtype=torch.bool)], 1
    )
    with torch.no_grad():
        clean = network(tpl, src)
        masked = network(torch.cat([tpl, junk], 1), src, template_valid=valid)
    torch.testing.assert_close(masked.transform, clean.transform, atol=1e-5, rtol=0)


def test_identity_pair_stays_at_identity(network, full_pairs):
    tpl = full_pairs.template[:1]
    with torch.no_grad():
        solution = network(tpl, tpl.flip(1))  # same points, another order
    torch.testing.assert_close(solution.transform[0], torch.eye(4), atol=1e-4, rtol=0)
    assert bool(solution.converged[0])


def test_training_mode_backpropagates_through_the_iterations():
    torch.manual_seed(0)
    net = PointNetLK(encoder_channels=(16, 32)).train()
    tpl = torch.rand(2, 64, 3)
    rot = se3_exp(torch.tensor([[0.0, 0.0, math.radians(10), 0, 0, 0]]))
    src = transform_points(rot, tpl)
    solution = net(tpl, src, max_iterations=3)
    solution.transform.sum().backward()
    assert net.encoder.linears[0].weight.grad.abs().sum() > 0
    assert solution.iterations.tolist() == [3, 3]


def test_save_and_load_round_trip(network, tmp_path, full_pairs):
    path = tmp_path / "lk.safetensors"
    network.save(path, {"note": "test"})
    loaded = PointNetLK.from_file(path)
    assert loaded.config == network.config
    with torch.no_grad():
        torch.testing.assert_close(
            loaded(full_pairs.template, full_pairs.source).transform,
            network(full_pairs.template, full_pairs.source).transform,
        )


def test_masknet_weights_are_refused_clearly(small_masknet_weights):
    with pytest.raises(MaskNetError, match="not PointNetLK weights.*masknet"):
        PointNetLK.from_file(small_masknet_weights)

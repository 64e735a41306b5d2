"""DCP, PRNet, PCRNet, RPM-Net: shapes, equivariances, building blocks, weights, training."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.geometry import (
    random_rotation,
)
from masknet.geometry.se3 import make_transform, quaternion_to_rotation
from masknet.models import DCP, PCRNet, PRNet, RPMNet
from masknet.models.layers import EdgeConvEncoder, gather_points, sinkhorn, soft_assignment
from masknet.models.rpmnet import point_pair_features

pytestmark = pytest.mark.usefixtures("one_thread")

TINY = {
    DCP: {"channels": [8, 8, 16], "embedding": 16, "k": 8, "heads": 2, "feedforward": 32},
    PRNet: {
        "channels": [8, 8, 16],
        "embedding": 16,
        "k": 8,
        "heads": 2,
        "feedforward": 32,
        "keypoints": 32,
    },
    PCRNet: {"encoder_channels": [16, 32], "head_channels": [32, 16]},
    RPMNet: {"features": 16, "k": 8, "parameter_channels": [16, 32]},
}


@pytest.fixture(scope="module")
def pairs():
    shapes = load_modelnet40(bundled_sample_path()).points[:3]
    return make_test_pairs(shapes[:, :128], 3, PairConfig(max_angle_deg=30), seed=4)


@pytest.mark.parametrize("cls", list(TINY), ids=lambda c: c.__name__)
def test_forward_returns_rigid_transforms_and_weights(cls, pairs):
    torch.manual_seed(0)
    net = cls(**TINY[cls]).eval()
    with torch.no_grad():
        solution = net(pairs.template, pairs.source, max_iterations=2)
    transform = solution.transform
    assert transform.shape == (3, 4, 4)
    rotation = transform[:, :3, :3]
    torch.testing.assert_close(rotation @ rotation.transpose(1, 2), torch.eye(3).expand(3, 3, 3))
    assert torch.allclose(torch.linalg.det(rotation), torch.ones(3), atol=1e-5)
    torch.testing.assert_close(transform[:, 3], torch.tensor([0.0, 0, 0, 1]).expand(3, 4))
    assert solution.iterations.tolist() == [2, 2, 2]
    if cls in (PRNet, RPMNet):  # correspondence weights over the template
        weight = solution.template_weight
        assert weight.shape == (3, 128) and weight.min() >= 0 and weight.max() <= 1
    else:
        assert solution.template_weight is None


@pytest.mark.parametrize("cls", list(TINY), ids=lambda c: c.__name__)
def test_translation_equivariance(cls, pairs):
    """Shifting the source by c changes the estimate by exactly that shift (centring)."""
    torch.manual_seed(0)
    net = cls(**TINY[cls]).double().eval()
    template, source = pairs.template.double(), pairs.source.double()
    shift = torch.tensor([0.7, -0.4, 1.3], dtype=torch.float64)
    with torch.no_grad():
        base = net(template, source, max_iterations=2).transform
        moved = net(template, source + shift, max_iterations=2).transform
    eye = torch.eye(3, dtype=torch.float64).expand(3, 3, 3)
    expected = base @ make_transform(eye, -shift.expand(3, 3))
    torch.testing.assert_close(moved, expected, atol=1e-6, rtol=1e-6)


def test_dgcnn_features_are_invariant_to_point_order(pairs):
    torch.manual_seed(0)
    encoder = EdgeConvEncoder((8, 16), 16, k=8).eval()
    points = pairs.template[:1]
    perm = torch.randperm(points.shape[1])
    with torch.no_grad():
        torch.testing.assert_close(encoder(points)[:, perm], encoder(points[:, perm]))


def test_edgeconv_matches_the_per_edge_formula():
    """The fast path (two per-point products and a gather) equals W [x_j - x_i; x_i] per edge."""
    torch.manual_seed(1)
    encoder = EdgeConvEncoder((6,), 4, k=5).double().eval()
    points = torch.randn(1, 12, 3, dtype=torch.float64)
    linear, norm = encoder.edges[0]
    idx = torch.cdist(points, points).topk(5, largest=False).indices[0]  # (12, 5)
    neighbours = points[0][idx]  # (12, 5, 3)
    centre = points[0][:, None].expand_as(neighbours)
    edge = linear(torch.cat([neighbours - centre, centre], -1))
    first = torch.nn.functional.leaky_relu(norm(edge), 0.2).amax(1)
    expected = torch.nn.functional.leaky_relu(encoder.out(first), 0.2)
    with torch.no_grad():
        torch.testing.assert_close(encoder(points)[0], expected.detach())


def test_gather_points_equals_an_expanded_gather_and_carries_gradients():
    """The index_select form picks the same rows as torch.gather, batch by batch."""
    torch.manual_seed(2)
    values = torch.randn(3, 10, 4, dtype=torch.float64, requires_grad=True)
    idx = torch.randint(0, 10, (3, 10, 5))
    expected = torch.gather(values, 1, idx.reshape(3, -1, 1).expand(-1, -1, 4)).reshape(3, 10, 5, 4)
    got = gather_points(values, idx)
    assert torch.equal(got, expected)
    got.sum().backward()
    counts = torch.zeros(3, 10, dtype=torch.float64).scatter_add_(
        1, idx.reshape(3, -1), torch.ones(3, 50, dtype=torch.float64)
    )
    torch.testing.assert_close(values.grad, counts[..., None].expand(-1, -1, 4))


def test_static_edgeconv_over_a_batch_equals_each_pair_alone():
    """Batched gathers keep each cloud's graph to its own points (offsets per batch element)."""
    torch.manual_seed(3)
    encoder = EdgeConvEncoder((6, 8), 5, k=4, dynamic=False, extra_channels=2).double().eval()
    points, extra = torch.randn(2, 9, 3, dtype=torch.float64), torch.randn(2, 9, 2).double()
    with torch.no_grad():
        batched = encoder(points, extra)
        alone = torch.cat([encoder(points[i : i + 1], extra[i : i + 1]) for i in range(2)])
    torch.testing.assert_close(batched, alone)


def test_soft_assignment_rows_sum_to_one_and_sinkhorn_with_slack_is_sub_stochastic():
    torch.manual_seed(2)
    q, k = torch.randn(2, 5, 8), torch.randn(2, 7, 8)
    weights = soft_assignment(q, k)
    torch.testing.assert_close(weights.sum(-1), torch.ones(2, 5))
    match = sinkhorn(torch.randn(2, 5, 7) * 3, iterations=20, slack=True)
    assert (match.sum(2) <= 1 + 1e-5).all() and (match.sum(1) <= 1 + 1e-5).all()
    square = sinkhorn(torch.randn(2, 6, 6), iterations=50, slack=False)
    torch.testing.assert_close(square.sum(1), torch.ones(2, 6), atol=1e-4, rtol=0)
    torch.testing.assert_close(square.sum(2), torch.ones(2, 6), atol=1e-4, rtol=0)


def test_point_pair_features_are_rotation_invariant_and_sign_free():
    torch.manual_seed(3)
    p, n = torch.randn(1, 10, 3, dtype=torch.float64), torch.randn(1, 10, 3, dtype=torch.float64)
    n = n / n.norm(dim=-1, keepdim=True)
    nb, nn_ = p[:, torch.arange(10).roll(1)][:, :, None], n[:, torch.arange(10).roll(1)][:, :, None]
    rot = random_rotation(1, 180, dtype=torch.float64)[0]
    base = point_pair_features(p, n, nb, nn_)
    rotated = point_pair_features(p @ rot.T, n @ rot.T, nb @ rot.T, nn_ @ rot.T)
    torch.testing.assert_close(rotated, base)
    torch.testing.assert_close(point_pair_features(p, -n, nb, nn_), base)


def test_quaternion_to_rotation_matches_known_rotations():
    half = torch.tensor([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)], dtype=torch.float64)
    expected = torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=torch.float64)
    torch.testing.assert_close(quaternion_to_rotation(half), expected)
    torch.testing.assert_close(quaternion_to_rotation(-3 * half), expected)  # unnormalised, -q


def test_pcrnet_starts_at_the_identity(pairs):
    net = PCRNet(**TINY[PCRNet]).eval()
    with torch.no_grad():
        solution = net(pairs.template, pairs.source, max_iterations=1)
    # centroid alignment only: R = I
    torch.testing.assert_close(solution.transform[:, :3, :3], torch.eye(3).expand(3, 3, 3))

"""Residual poses: the pairs as a registration round leaves them."""

from __future__ import annotations

import pytest
import torch

from masknet.data import bundled_sample_path, load_modelnet40
from masknet.data.pairs import PairConfig, make_pairs
from masknet.data.residuals import ResidualConfig, residual_pairs
from masknet.geometry.se3 import rotation_angle, transform_points


@pytest.fixture(scope="module")
def pairs():
    shapes = torch.from_numpy(load_modelnet40(bundled_sample_path(), "test").points[:16, :256])
    return make_pairs(shapes, PairConfig(), torch.Generator().manual_seed(0))


def test_the_returned_transform_undoes_the_residual(pairs):
    out = residual_pairs(pairs, ResidualConfig(), torch.Generator().manual_seed(1))
    truth = transform_points(pairs.transform.double(), pairs.source.double())
    back = transform_points(out.transform.double(), out.source.double())
    assert torch.allclose(back, truth, atol=1e-5)
    # the residual is a real motion, not the identity
    moved = (out.source.double() - truth).norm(dim=-1).mean(1)
    assert float(moved.max()) > 0.05
    assert torch.equal(out.mask, pairs.mask) and torch.equal(out.template, pairs.template)


def test_angles_follow_the_config(pairs):
    near = ResidualConfig(near_fraction=1.0, wide_fraction=0.0, near_deg=2.0)
    out = residual_pairs(pairs, near, torch.Generator().manual_seed(2))
    angles = torch.rad2deg(rotation_angle(out.transform[:, :3, :3].double()))
    assert float(angles.max()) <= 2.0 + 1e-4 and float(angles.max()) > 0.1
    wide = ResidualConfig(near_fraction=0.0, wide_fraction=1.0, max_deg=45.0)
    angles = torch.rad2deg(
        rotation_angle(
            residual_pairs(pairs, wide, torch.Generator().manual_seed(2))
            .transform[:, :3, :3]
            .double()
        )
    )
    assert float(angles.max()) <= 45.0 + 1e-4 and float(angles.max()) > 10.0


def test_seeded(pairs):
    a = residual_pairs(pairs, ResidualConfig(), torch.Generator().manual_seed(3))
    b = residual_pairs(pairs, ResidualConfig(), torch.Generator().manual_seed(3))
    c = residual_pairs(pairs, ResidualConfig(), torch.Generator().manual_seed(4))
    assert torch.equal(a.source, b.source) and not torch.equal(a.source, c.source)


def test_bad_config_is_refused():
    with pytest.raises(ValueError, match="near_fraction"):
        ResidualConfig(near_fraction=0.8, wide_fraction=0.5)
    with pytest.raises(ValueError, match="max_deg"):
        ResidualConfig(max_deg=200)

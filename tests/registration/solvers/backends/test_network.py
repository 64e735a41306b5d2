"""masknet.registration.solvers.backends.network: the adapter of the learned registration networks.
The shipped PointNetLK on ModelNet40 pairs with a known transform, and a stub network that
shows what the adapter hands a network (points in use, unit scale, sampling)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from masknet.errors import MaskNetError
from masknet.registration.solvers.backends.network import run_network
from masknet.registration.terms.options import NetworkOptions, PointNetLKOptions

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def lk(shipped_pointnetlk) -> PointNetLKOptions:
    return PointNetLKOptions(network=shipped_pointnetlk, max_iterations=10)


def _unit_radius(points: np.ndarray) -> float:
    """The largest distance from the bounding-box centre (how the networks' training shapes
    were scaled), written out here."""
    mid = (points.max(0) + points.min(0)) / 2
    return float(np.sqrt(((points - mid) ** 2).sum(1)).max())


def test_pointnetlk_recovers_the_known_transform_through_the_mask(known_pairs, lk, pose_error):
    """Measured: 3.2e-5 deg and 8.8e-7 at most, every pair converged (4-7 iterations),
    feature residual 7.4e-7 at most. Bounds 1e-3 deg, 1e-5, residual 1e-5. Without the
    mask the partial source matches the whole template's features badly: measured 3.1 to
    36 deg off, residual 6.6e-3 at least; bounds 1 deg and 1e-3."""
    t, s, truth, mask = known_pairs
    run = run_network(t, s, mask, None, lk)
    degrees, shift = pose_error(run.transform, truth)
    assert degrees.max() < 1e-3 and shift.max() < 1e-5, (degrees, shift)
    assert run.transform.dtype == np.float64 and run.correspondence_inliers is None
    assert set(run.info) == {"iterations", "converged", "feature_residual"}
    assert run.info["converged"].all()
    assert ((run.info["iterations"] >= 1) & (run.info["iterations"] <= 10)).all()
    assert (run.info["feature_residual"] < 1e-5).all()
    unmasked = run_network(t, s, None, None, lk)
    assert pose_error(unmasked.transform, truth)[0].min() > 1
    assert (unmasked.info["feature_residual"] > 1e-3).all()


def test_the_network_sees_the_masked_points_at_unit_scale(known_pairs, shipped_pointnetlk):
    """The adapter's answer is the network's on the masked template points and the source,
    both divided by the whole template's radius, with the translation scaled back; computed
    here with the network called directly. Measured 3e-10; bound 1e-6."""
    t, s, _, mask = known_pairs
    options = PointNetLKOptions(network=shipped_pointnetlk, max_iterations=10, tolerance=1e-5)
    run = run_network(t[:1], s[:1], mask[:1], None, options)
    radius = _unit_radius(t[0])
    with torch.inference_mode():
        direct = shipped_pointnetlk(
            torch.from_numpy(t[0][mask[0]] / radius).float()[None],
            torch.from_numpy(s[0] / radius).float()[None],
            max_iterations=10,
            tolerance=1e-5,
        )
    expected = direct.transform[0].double().numpy()
    expected[:3, 3] *= radius
    np.testing.assert_allclose(run.transform[0], expected, atol=1e-6, rtol=0)
    assert run.info["iterations"][0] == int(direct.iterations[0])


def test_masked_out_template_points_take_no_part(known_pairs, lk, extent_decoys):
    """The masked-out points pulled inwards (the template's box and radius, its scale, kept)
    leave the answer exactly as it was; without the mask the same change moves it."""
    t, s, _, mask = known_pairs
    decoyed = extent_decoys(t, mask)
    assert not np.array_equal(decoyed, t)
    clean = run_network(t, s, mask, None, lk)
    moved = run_network(decoyed, s, mask, None, lk)
    np.testing.assert_array_equal(moved.transform, clean.transform)
    unmasked = (run_network(x, s, None, None, lk).transform for x in (t, decoyed))
    assert np.abs(next(unmasked) - next(unmasked)).max() > 1e-3


def _rejecting(known_pairs, seed: int = 0):
    """A source mask rejecting 100 and 250 random points of the two pairs, and the sources
    with those points replaced by far outliers (50 units away; the shapes' radius is 1)."""
    rng = np.random.default_rng(seed)
    source = known_pairs.source
    keep = np.ones(source.shape[:2], bool)
    for b, count in enumerate((100, 250)):
        keep[b, rng.choice(source.shape[1], count, replace=False)] = False
    far = source.copy()
    far[~keep] = 50.0 + rng.normal(size=((~keep).sum(), 3))
    return keep, far


def test_rejected_source_points_take_no_part(known_pairs, lk, pose_error):
    """One pair at a time the network sees exactly the kept points: outliers in the
    rejected slots change nothing. Without the source mask they wreck it (measured 60 and
    100 deg; bound 20)."""
    t, _, truth, mask = known_pairs
    keep, far = _rejecting(known_pairs)
    for b in range(2):
        one = slice(b, b + 1)
        with_outliers = run_network(t[one], far[one], mask[one], keep[one], lk)
        kept_alone = run_network(t[one], far[one][:, keep[b]], mask[one], None, lk)
        np.testing.assert_array_equal(with_outliers.transform, kept_alone.transform)
    unmasked = run_network(t, far, mask, None, lk)
    assert pose_error(unmasked.transform, truth)[0].min() > 20


def test_a_pointnetlk_batch_equals_its_pairs(known_pairs, lk):
    """A batch with source masks keeping 617 and 467 points: the rejected slots are filled
    with repeats of kept points, which PointNet's max pool cannot see (and LK converges
    from the shifted centroid they give). Measured 7.3e-7 on the transforms' entries;
    bound 1e-5 (float32)."""
    t, _, _, mask = known_pairs
    keep, far = _rejecting(known_pairs)
    batch = run_network(t, far, mask, keep, lk)
    for b in range(2):
        one = slice(b, b + 1)
        single = run_network(t[one], far[one], mask[one], keep[one], lk)
        np.testing.assert_allclose(batch.transform[b], single.transform[0], atol=1e-5, rtol=0)


def test_a_dcp_batch_with_a_source_mask_equals_its_pairs(known_pairs):
    from masknet.models import REGISTRATION_NETWORKS

    dcp = NetworkOptions(network=REGISTRATION_NETWORKS["dcp"].pretrained().eval(), max_iterations=1)
    t, s, _, mask = known_pairs
    keep, far = _rejecting(known_pairs)
    plain = run_network(t, s, mask, None, dcp)  # the batch itself is not the cause
    masked = run_network(t, far, mask, keep, dcp)
    for b in range(2):
        one = slice(b, b + 1)
        single = run_network(t[one], s[one], mask[one], None, dcp)
        np.testing.assert_allclose(plain.transform[b], single.transform[0], atol=1e-5, rtol=0)
        single = run_network(t[one], far[one], mask[one], keep[one], dcp)
        np.testing.assert_allclose(masked.transform[b], single.transform[0], atol=1e-5, rtol=0)


def test_scaled_clouds_give_the_same_rotation_and_scaled_translation(known_pairs, lk):
    """The adapter divides by the template's radius: clouds 10 times as large give the same
    rotation and 10 times the translation. Measured 4.9e-7 and 1.5e-6; bounds 1e-5, 1e-4."""
    t, s, _, mask = known_pairs
    unit = run_network(t, s, mask, None, lk)
    large = run_network(10 * t, 10 * s, mask, None, lk)
    np.testing.assert_allclose(large.transform[:, :3, :3], unit.transform[:, :3, :3], atol=1e-5)
    np.testing.assert_allclose(
        large.transform[:, :3, 3], 10 * unit.transform[:, :3, 3], atol=1e-4, rtol=0
    )


def test_masks_of_different_sizes_run_pair_by_pair(known_pairs, lk):
    t, s, _, mask = known_pairs
    unequal = mask.copy()
    unequal[0, np.flatnonzero(unequal[0])[:50]] = False
    batch = run_network(t, s, unequal, None, lk)
    for b in range(2):
        one = slice(b, b + 1)
        single = run_network(t[one], s[one], unequal[one], None, lk)
        np.testing.assert_array_equal(batch.transform[b], single.transform[0])
        for key, value in single.info.items():
            np.testing.assert_array_equal(batch.info[key][b], value[0])


def test_a_mask_of_fewer_than_three_points_is_refused(known_pairs, lk):
    t, s, _, _ = known_pairs
    mask = np.zeros(t.shape[:2], bool)
    mask[:, :2] = True
    with pytest.raises(MaskNetError, match=r"the mask kept 2 template point\(s\)"):
        run_network(t, s, mask, None, lk)


class _Stub(torch.nn.Module):
    """A network that records what it is given (in eval mode or not) and answers a fixed
    translation; its template weight marks the points with x > 0 as inliers."""

    shift = (0.1, -0.2, 0.3)

    def __init__(self, input_points: int) -> None:
        super().__init__()
        self.config = {"input_points": input_points}
        self.anchor = torch.nn.Parameter(torch.zeros(()))
        self.calls: list[tuple[torch.Tensor, torch.Tensor, int, bool]] = []

    def forward(self, template, source, max_iterations):
        self.calls.append((template.clone(), source.clone(), max_iterations, self.training))
        b = template.shape[0]
        transform = torch.eye(4).repeat(b, 1, 1)
        transform[:, :3, 3] = torch.tensor(self.shift)
        return SimpleNamespace(
            transform=transform,
            iterations=torch.full((b,), max_iterations),
            template_weight=(template[..., 0] > 0).float(),
        )


def test_clouds_above_the_networks_size_are_sampled_from_the_points_in_use(known_pairs):
    """A network built for 300 points: the 717 masked template points are sampled to 300
    and the 717-point source in the same ratio (300); the translation comes back in the
    clouds' units; inliers are the sampled masked points the network weighs >= 0.5."""
    t, s, _, mask = known_pairs
    stub = _Stub(300).train()
    run = run_network(10 * t, 10 * s, mask, None, NetworkOptions(network=stub, max_iterations=4))
    assert stub.training  # the caller's mode is restored ...
    assert len(stub.calls) == 1
    seen_t, seen_s, iterations, training = stub.calls[0]
    assert not training and iterations == 4  # ... after an eval-mode call
    n_used = int(mask[0].sum())
    assert seen_t.shape == (2, 300, 3)
    assert seen_s.shape == (2, round(s.shape[1] * 300 / n_used), 3)
    np.testing.assert_array_equal(run.info["iterations"], [4, 4])
    for b in range(2):
        radius = _unit_radius(10 * t[b])
        # every point the network saw is a masked template point, at unit scale
        masked = 10 * t[b][mask[b]] / radius
        gaps = np.abs(seen_t[b].double().numpy()[:, None] - masked[None]).max(-1).min(1)
        assert gaps.max() < 1e-6
        gaps = np.abs(seen_s[b].double().numpy()[:, None] - 10 * s[b][None] / radius)
        assert gaps.max(-1).min(1).max() < 1e-6
        np.testing.assert_allclose(run.transform[b, :3, 3], radius * np.array(_Stub.shift), 1e-6)
        inliers = run.correspondence_inliers[b]
        assert not inliers[~mask[b]].any()
        assert (t[b][inliers, 0] > 0).all()
        assert inliers.sum() == int((seen_t[b][:, 0] > 0).sum())

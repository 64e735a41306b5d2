"""The pipelines the experiments compare (keyword arguments of :func:`masknet.register`) and
which weights ship."""

from __future__ import annotations

from masknet.errors import MaskNetError
from masknet.evaluation.registration import PIPELINES, x_and_mask_x
from masknet.models import REGISTRATION_NETWORKS
from masknet.models.masknet import MaskNet
from masknet.models.weights import shipped_weights_path
from masknet.registration.terms.methods import METHOD_TITLES

__all__ = [
    "LEARNED",
    "PEERS",
    "PEER_PAIRS",
    "SWEEP_PIPELINES",
    "shipped",
    "shipped_masknet",
    "sweep_pipelines",
]

# X and Mask-X for each method that has shipped weights (the sweeps' lines).
SWEEP_PIPELINES = x_and_mask_x(["icp", "pointnetlk"])
# The learned back-ends beyond PointNetLK, by display name (method names of register()).
LEARNED = {METHOD_TITLES[m]: m for m in REGISTRATION_NETWORKS if m != "pointnetlk"}
# Open3D's global methods on FPFH features.
PEERS = {name: PIPELINES[name] for name in ("Open3D RANSAC (FPFH)", "Open3D FGR (FPFH)")}
PEER_PAIRS = 200  # the global methods take ~0.1 s a pair: sweeps run them on the first 200


def shipped(method: str) -> bool:
    """Whether the package ships weights for a learned registration method."""
    prefix = REGISTRATION_NETWORKS[method].weights_prefix
    return shipped_weights_path(f"{prefix}modelnet40.safetensors").exists()


def sweep_pipelines() -> dict[str, dict]:
    """X and Mask-X for ICP, PointNetLK and every learned back-end whose weights ship."""
    return SWEEP_PIPELINES | x_and_mask_x(
        {name: method for name, method in LEARNED.items() if shipped(method)}
    )


def shipped_masknet(name: str) -> MaskNet | None:
    """The shipped MaskNet weights ``name`` (e.g. ``"denoise_modelnet40"``), None if they
    do not ship."""
    try:
        return MaskNet.pretrained(name)
    except MaskNetError:
        return None

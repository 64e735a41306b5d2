"""Models: the PointNet encoder, MaskNet, CrossMaskNet, the two-sided MaskNet, the refinement mask, and the
learned registration networks."""

from masknet.models.cross_masknet import CrossMaskNet
from masknet.models.dcp import DCP
from masknet.models.layers import RegistrationSolution
from masknet.models.masknet import FusedMaskNet, MaskNet, ScoredMask, select_mask
from masknet.models.pcrnet import PCRNet
from masknet.models.pointnet import PointNetEncoder, fold_batchnorm
from masknet.models.pointnetlk import LKSolution, PointNetLK
from masknet.models.prnet import PRNet
from masknet.models.refine import RefineMaskNet
from masknet.models.rpmnet import RPMNet
from masknet.models.two_sided import TwoSidedMaskNet

# Learned registration networks by method name. Each takes (template, source,
# max_iterations=...) and returns a solution with a ``transform`` (B, 4, 4).
REGISTRATION_NETWORKS = {
    "pointnetlk": PointNetLK,
    "dcp": DCP,
    "prnet": PRNet,
    "pcrnet": PCRNet,
    "rpmnet": RPMNet,
}

__all__ = [
    "CrossMaskNet",
    "DCP",
    "FusedMaskNet",
    "LKSolution",
    "MaskNet",
    "PCRNet",
    "PRNet",
    "PointNetLK",
    "PointNetEncoder",
    "REGISTRATION_NETWORKS",
    "RPMNet",
    "RefineMaskNet",
    "RegistrationSolution",
    "ScoredMask",
    "TwoSidedMaskNet",
    "fold_batchnorm",
    "select_mask",
]

"""Models: the PointNet encoder and MaskNet."""

from masknet.models.masknet import FusedMaskNet, MaskNet, select_mask
from masknet.models.pointnet import PointNetEncoder, fold_batchnorm
from masknet.models.pointnetlk import LKSolution, PointNetLK

__all__ = [
    "FusedMaskNet",
    "LKSolution",
    "MaskNet",
    "PointNetLK",
    "PointNetEncoder",
    "fold_batchnorm",
    "select_mask",
]

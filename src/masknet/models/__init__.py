"""Models: the PointNet encoder and MaskNet."""

from masknet.models.masknet import FusedMaskNet, MaskNet, select_mask
from masknet.models.pointnet import PointNetEncoder, fold_batchnorm

__all__ = ["FusedMaskNet", "MaskNet", "PointNetEncoder", "fold_batchnorm", "select_mask"]

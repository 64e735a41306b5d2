"""Geometry: the SE(3) module, the k-NN helper, rigid alignment, and clouds as the networks
take them (validated batches, unit radius)."""

from masknet.geometry.align import centroid, rigid_align
from masknet.geometry.clouds import MIN_POINTS, as_cloud_batch, median_spacing, unit_radius
from masknet.geometry.knn import KNN, knn_points
from masknet.geometry.se3 import (
    invert_transform,
    make_transform,
    random_rotation,
    rotation_error_deg,
    se3_exp,
    so3_exp,
    split_transform,
    transform_points,
    translation_error,
)

__all__ = [
    "KNN",
    "MIN_POINTS",
    "as_cloud_batch",
    "centroid",
    "knn_points",
    "invert_transform",
    "make_transform",
    "median_spacing",
    "random_rotation",
    "rigid_align",
    "rotation_error_deg",
    "se3_exp",
    "so3_exp",
    "split_transform",
    "transform_points",
    "translation_error",
    "unit_radius",
]

"""Data: ModelNet40 readers and seeded pair generation."""

from masknet.data.modelnet import PointCloudSet, bundled_sample_path, load_modelnet40
from masknet.data.pairs import (
    PairConfig,
    Pairs,
    iterate_pairs,
    make_pairs,
    make_test_pairs,
    sample_pair,
)

__all__ = [
    "PointCloudSet",
    "bundled_sample_path",
    "load_modelnet40",
    "PairConfig",
    "Pairs",
    "iterate_pairs",
    "make_pairs",
    "make_test_pairs",
    "sample_pair",
]

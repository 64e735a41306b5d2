"""What FPFH descriptors add beside the shipped MaskNet, with no training.

    python scripts/descriptor_blend.py --data ../shared/data/modelnet40/modelnet40_1024_int16.npz --pairs 200

On seeded ModelNet40 test pairs (random views keeping 70%, rotations up to 45 degrees), each
template point is ranked by the distance of its FPFH descriptor (two median spacings, normals
towards the centroid, 100 neighbours) to the nearest source descriptor, and that rank is
averaged with the rank of MaskNet's score at each weight w. Prints the top-k precision
(k = the source's points) of each blend: w = 0 is MaskNet alone, "descriptors" the ranking
alone.
"""

from __future__ import annotations

import argparse

import numpy as np

from masknet.cli import run_script

WEIGHTS = (0.0, 0.25, 0.5, 1.0, 2.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True, help="ModelNet40 folder or .npz")
    parser.add_argument("--pairs", type=int, default=200)
    args = parser.parse_args()

    import open3d as o3d
    from scipy.spatial import cKDTree
    from scipy.stats import rankdata

    from masknet.data import PairConfig, load_modelnet40, make_test_pairs
    from masknet.geometry.clouds import median_spacing
    from masknet.geometry.features import fpfh_features
    from masknet.models import MaskNet

    shapes = load_modelnet40(args.data, "test").points
    pairs = make_test_pairs(shapes, args.pairs, PairConfig(), seed=0)
    scores = MaskNet.pretrained().scorer("fp32")(pairs.template, pairs.source).detach().numpy()

    def features(cloud: np.ndarray, voxel: float) -> np.ndarray:
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud))
        return np.asarray(fpfh_features(o3d, pc, voxel, 100, orient=True).data).T

    found = {w: [] for w in (*WEIGHTS, "descriptors")}
    for t, s, m, net in zip(
        pairs.template.double().numpy(),
        pairs.source.double().numpy(),
        pairs.mask.numpy(),
        scores,
        strict=True,
    ):
        voxel = 2 * median_spacing(t)
        distance = cKDTree(features(s, voxel)).query(features(t, voxel))[0]
        by_net, by_descriptor = rankdata(net) / len(net), rankdata(-distance) / len(net)
        for w in found:
            blend = by_descriptor if w == "descriptors" else by_net + w * by_descriptor
            found[w].append(m[np.argsort(-blend, kind="stable")[: len(s)]].mean())
    for w, precision in found.items():
        print(f"w = {w}: top-k precision {np.mean(precision):.3f}")


if __name__ == "__main__":
    run_script(main)

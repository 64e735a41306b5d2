"""Why the default slides along a room's planes on sparse scene fragments.

    python scripts/slide_diagnosis.py [--draws 8] [--points 2000]

The 3DMatch pair of the evaluation scans, the source randomly subsampled to ``--points``
points and the template to 1.2 times as many, ``--draws`` seeded draws. For each draw: the
default's error; the project's score (the truncated least-squares fit the pipelines rank
poses by, at 1.5 template spacings) of the pose it returned and of the ground truth; and
the verdict on it; where the ground truth settles under 30 iterations of point-to-point and of point-to-plane
ICP with pairs cut at 3 spacings. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from masknet.cli import run_script


def main() -> None:
    from masknet import assess_registration, register
    from masknet.evaluation.registration import pose_errors
    from masknet.experiments.scans import THREEDMATCH_FILES, load_pair, scans_folder
    from masknet.geometry.clouds import median_spacing
    from masknet.geometry.knn import cloud_tree
    from masknet.geometry.normals import estimate_normals
    from masknet.registration.judge.fit import FIT_SPACINGS, pose_fit
    from masknet.registration.solvers.icp import icp

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=8)
    parser.add_argument("--points", type=int, default=2000)
    args = parser.parse_args()
    template_all, source_all, truth = load_pair(scans_folder(), *THREEDMATCH_FILES)
    warnings.simplefilter("ignore")

    def error(pose) -> str:
        rot, trans = pose_errors(np.asarray(pose).reshape(1, 4, 4), truth[None])
        return f"{rot[0]:.1f}°, {100 * trans[0]:.0f} cm"

    print(
        "| draw | default | its path | its verdict | score: default's pose / ground truth | "
        "truth after point-to-point ICP | truth after point-to-plane ICP |"
    )
    print("|---|---|---|---|---|---|---|")
    for draw in range(args.draws):
        rng = np.random.default_rng(draw)
        source = source_all[rng.choice(len(source_all), args.points, replace=False)]
        template = template_all[
            rng.choice(len(template_all), int(1.2 * args.points), replace=False)
        ]
        result = register(template, source)
        tree, spacing = cloud_tree(template), median_spacing(template)
        limit = FIT_SPACINGS * spacing
        found, true = (
            pose_fit(tree, source, result.transform, limit),
            pose_fit(tree, source, truth, limit),
        )
        normals = np.asarray(estimate_normals(template)[0])
        settle = [
            icp(template, source, init=truth, max_iterations=30, max_correspondence_distance=3 * spacing,
                template_tree=tree, template_normals=n).transform
            for n in (None, normals)
        ]  # fmt: skip
        print(
            f"| {draw} | {error(result.transform)} | {result.info.get('path')} | "
            f"{assess_registration(template, source, result.transform).verdict} | "
            f"{found.score:.3f} / {true.score:.3f} | {error(settle[0])} | {error(settle[1])} |"
        )


if __name__ == "__main__":
    run_script(main)

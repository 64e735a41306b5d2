"""Where real pairs and mixed-unit pairs lie for the unit check (masknet.registration.terms.units).

    python scripts/mixed_units.py [--scans ../shared/data/scans]

For the real pairs of the evaluation scans (the 3DMatch pair in two versions, the room
scans, the carton in its Kinect scene), as given, with one side randomly subsampled 8
times, and with one side scaled by 10, 100 and 1000: the source/template ratio of the
extents (median distance from the median point) and of the point spacings, the check's
verdict, and its time. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from masknet.cli import run_script

PAIRS = {
    "3DMatch": ("geotransformer_demo_ref.npy", "geotransformer_demo_src.npy"),
    "3DMatch (Open3D)": ("o3d_feature_cloud_bin_0.pcd", "o3d_feature_cloud_bin_1.pcd"),
    "rooms": ("room_scan1.pcd", "room_scan2.pcd"),
    "carton in its scene": ("milk.pcd", "milk_cartoon_all_small_clorox.pcd"),
}


def main() -> None:
    from masknet.experiments.scans import scans_folder
    from masknet.io import read_points
    from masknet.registration.terms.units import check_units

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=Path, default=None, help="the evaluation scans")
    args = parser.parse_args()
    folder = args.scans or scans_folder()

    def load(name: str) -> np.ndarray:
        path = folder / name
        return np.load(path) if path.suffix == ".npy" else read_points(path, drop_nonfinite=True)

    rng = np.random.default_rng(0)
    print("| pair | case | extent ratio | spacing ratio | check | ms |")
    print("|---|---|---|---|---|---|")
    for name, (a, b) in PAIRS.items():
        template, source = load(a), load(b)
        cases = {
            "as given": (template, source),
            "source subsampled 8x": (template, source[rng.permutation(len(source))[::8]]),
            "template subsampled 8x": (template[rng.permutation(len(template))[::8]], source),
        }
        for factor in (10, 100, 1000):
            cases[f"source x{factor}"] = (template, factor * source)
            cases[f"template x{factor}"] = (factor * template, source)
        check_units(template, source)  # warm
        for case, (t, s) in cases.items():
            tic = time.perf_counter()
            check = check_units(t, s)
            ms = 1e3 * (time.perf_counter() - tic)
            verdict = "-"
            if check.mixed:
                verdict = f"mixed, about {max(check.factor, 1 / check.factor):,.0f}x"
            spacing = "-" if np.isnan(check.spacing_ratio) else f"{check.spacing_ratio:.3g}"
            print(
                f"| {name} | {case} | {check.extent_ratio:.3g} | {spacing} | {verdict} | {ms:.1f} |"
            )


if __name__ == "__main__":
    run_script(main)

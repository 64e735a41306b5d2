"""Where the default's time goes on the real pairs: ``result.times`` of one call per pair.

    python scripts/real_pair_stages.py [--repeats 3]

The 3DMatch pair, the two room scans and the carton in its Kinect scene (metres), each
registered ``--repeats`` times after a warm-up call; prints the median of each stage of
``result.times`` (seconds; a stage that did not run is blank) as a Markdown table. Run it
at two revisions (``PYTHONPATH=<checkout>/src``) for a before/after table.
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from masknet.cli import run_script

PAIRS = {
    "3DMatch pair": ("geotransformer_demo_ref.npy", "geotransformer_demo_src.npy"),
    "two room scans": ("room_scan1.pcd", "room_scan2.pcd"),
    "carton in the Kinect scene": ("milk.pcd", "milk_cartoon_all_small_clorox.pcd"),
}


def main() -> None:
    from masknet import register
    from masknet.experiments.scans import load_pair, scans_folder

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    folder = scans_folder()
    rows, stages = {}, []
    for name, files in PAIRS.items():
        template, source, _ = load_pair(folder, *files, None)
        register(template[:2000], source[:2000])  # warm start
        calls = [register(template, source) for _ in range(args.repeats)]
        times = {k: float(np.median([c.times.get(k, 0.0) for c in calls])) for k in calls[0].times}
        rows[name] = (times, str(calls[0].info.get("path", "")))
        stages += [k for k in times if k not in stages and k != "total"]
    print("| pair | path | " + " | ".join(stages) + " | total |")
    print("|---|---|" + "---|" * (len(stages) + 1))
    for name, (times, path) in rows.items():
        cells = [f"{times[k]:.3f}" if times.get(k) else "" for k in stages]
        print(f"| {name} | {path} | " + " | ".join(cells) + f" | {times['total']:.3f} |")


if __name__ == "__main__":
    run_script(main)

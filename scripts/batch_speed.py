"""masknet register-many against the same pairs one call at a time, on this machine.

    python scripts/batch_speed.py [--pairs 200] [--workers 2] [--scans DIR] [--work DIR]

Cuts ``--pairs`` seeded pairs from the evaluation scans (sensor-like views of crops,
masknet.data.scans: 2,048-point templates, 70% views, rotations up to 45 degrees), saves
them as .npy files with a list file, then, in one run:

1. **one call at a time**: ``register`` then ``assess_registration`` for each pair, in this
   process (torch's threads: one per core), the networks loaded once before the clock;
2. **the batch**: ``masknet register-many --list`` with ``--workers`` processes, wall time
   of the whole command (start-up and model loading included);
3. **the results**: the largest difference between the two runs' transforms, and the pairs
   whose verdicts differ;
4. **a kill**: the batch again into a fresh folder, killed (SIGKILL, nothing graceful) once
   about half of the pairs are written, then run again: how many it reports as finished
   earlier, and whether their files were left untouched;
5. **a cluster**: the batch on a local Dask cluster of 2 worker processes (``--scheduler``),
   its transforms against the batch's.

Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from masknet.cli import run_script


def make_pairs(scans_dir: Path, count: int, work: Path) -> Path:
    """``count`` pairs as .npy files in ``work``, and their list file."""
    from masknet.data.scans import load_scans, make_scan_test_pairs
    from masknet.data.views import ViewConfig

    # The scans large enough for a 2,048-point view pair (twice as many points).
    scans = [scan for scan in load_scans(scans_dir) if len(scan.points) >= 4096]
    per_scan = -(-count // len(scans))
    view = ViewConfig(template_points=2048, noise_sigma=0.002, random_noise=False)
    pairs, names = make_scan_test_pairs(scans, per_scan, view, seed=0)
    work.mkdir(parents=True, exist_ok=True)
    lines = []
    for i in range(count):
        np.save(work / f"t{i:03d}.npy", pairs.template[i].double().numpy())
        np.save(work / f"s{i:03d}.npy", pairs.source[i].double().numpy())
        lines.append(f"t{i:03d}.npy s{i:03d}.npy pair{i:03d}_{names[i]}")
    (work / "pairs.txt").write_text("\n".join(lines) + "\n")
    return work / "pairs.txt"


def one_at_a_time(
    listing: Path, threads: int | None = None
) -> tuple[float, dict[str, tuple[np.ndarray, str]]]:
    """Seconds for every pair through register + assess_registration in this process
    (torch's threads: ``threads``, default as torch sets them)."""
    import torch

    from masknet import assess_registration, register
    from masknet.registration.plan import default_model, default_two_sided

    before = torch.get_num_threads()
    if threads:
        torch.set_num_threads(threads)

    default_model(), default_two_sided()  # loaded before the clock, as the batch loads once
    rows = [line.split() for line in listing.read_text().splitlines()]
    clouds = [(np.load(listing.parent / t), np.load(listing.parent / s), n) for t, s, n in rows]
    tic = time.perf_counter()
    out = {}
    for template, source, name in clouds:
        result = register(template, source)
        kept = source if result.source_mask is None else source[result.source_mask]
        out[name] = (
            result.transform,
            assess_registration(template, kept, result.transform).verdict,
        )
    seconds = time.perf_counter() - tic
    torch.set_num_threads(before)
    return seconds, out


def batch(listing: Path, out: Path, *extra: str) -> tuple[float, subprocess.CompletedProcess]:
    command = [sys.executable, "-m", "masknet.cli", "register-many", "--list", str(listing)]
    tic = time.perf_counter()
    done = subprocess.run(
        [*command, "-o", str(out), "--exit-zero", *extra], capture_output=True, text=True
    )
    return time.perf_counter() - tic, done


def records(out: Path) -> dict[str, tuple[np.ndarray, str]]:
    found = {}
    for path in out.glob("*.json"):
        record = json.loads(path.read_text())
        if record["status"] == "registered":
            found[record["name"]] = (np.array(record["transform"]), record["verdict"])
    return found


def interrupted(listing: Path, out: Path, workers: int, total: int) -> dict[str, object]:
    """Kill a batch half-way (SIGKILL), run it again; what the second run redid."""
    command = [sys.executable, "-m", "masknet.cli", "register-many", "--list", str(listing)]
    command += ["-o", str(out), "--workers", str(workers), "--exit-zero"]
    process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    while len(list(out.glob("*.json"))) < total // 2 and process.poll() is None:
        time.sleep(0.2)
    process.send_signal(signal.SIGKILL)
    first_err = process.communicate(timeout=300)[1]
    kept = {p.name: p.stat().st_mtime_ns for p in out.glob("*.json")}
    again = subprocess.run(command, capture_output=True, text=True)
    untouched = all((out / name).stat().st_mtime_ns == t for name, t in kept.items())
    said = [line for line in again.stderr.splitlines() if "finished earlier" in line]
    return {
        "finished before the kill": len(kept),
        "first run's exit status": process.returncode,
        "first run's last line": first_err.strip().splitlines()[-1] if first_err.strip() else "",
        "second run said": said[0] if said else "",
        "finished files untouched": untouched,
        "records after the second run": len(list(out.glob("*.json"))),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=200)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--scans", type=Path, default=None)
    parser.add_argument("--work", type=Path, default=Path("batch_speed_work"))
    parser.add_argument(
        "--parts", default="speed,kill,cluster", help="which of speed, kill, cluster to run"
    )
    args = parser.parse_args()
    parts = set(args.parts.split(","))
    from masknet.experiments.scans import scans_folder

    listing = make_pairs(args.scans or scans_folder(), args.pairs, args.work)
    if "speed" in parts:
        speed(listing, args)
    if "kill" in parts:
        stop = interrupted(listing, args.work / "killed", args.workers, args.pairs)
        print("\nkill and rerun: " + "; ".join(f"{k}: {v}" for k, v in stop.items()))
    if "cluster" in parts:
        cluster(listing, args)


def speed(listing: Path, args: argparse.Namespace) -> None:
    """The loop (torch's default threads, then one), the batch, and their results."""
    single_s, single = one_at_a_time(listing)
    one_thread_s, _ = one_at_a_time(listing, threads=1)
    batch_s, _ = batch(listing, args.work / "batch", "--workers", str(args.workers))
    found = records(args.work / "batch")
    common = sorted(set(single) & set(found))
    diff = max(float(np.abs(single[n][0] - found[n][0]).max()) for n in common)
    verdicts = sum(single[n][1] != found[n][1] for n in common)
    print(
        f"| pairs | one call at a time (s) | the same, one thread (s) | register-many, "
        f"{args.workers} workers (s) | speed-up | over one thread |"
    )
    print("|---|---|---|---|---|---|")
    print(
        f"| {len(common)} of {args.pairs} | {single_s:.1f} | {one_thread_s:.1f} | {batch_s:.1f} "
        f"| {single_s / batch_s:.2f} | {one_thread_s / batch_s:.2f} |"
    )
    print(f"\nlargest transform difference: {diff:.3g}; verdicts that differ: {verdicts}")


def cluster(listing: Path, args: argparse.Namespace) -> None:
    """The batch on a local Dask cluster of two worker processes, against the batch's."""
    try:
        import distributed
    except ImportError:
        print("\ncluster: distributed is not installed (pip install 'masknet[cluster]')")
        return
    found = records(args.work / "batch")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as local:
        cluster_s, _ = batch(listing, args.work / "cluster", "--scheduler", local.scheduler_address)
    on_cluster = records(args.work / "cluster")
    same = [n for n in found if n in on_cluster]
    worst = max(float(np.abs(found[n][0] - on_cluster[n][0]).max()) for n in same)
    print(
        f"\ncluster (local, 2 worker processes): {len(on_cluster)} registered in {cluster_s:.1f} s; "
        f"largest transform difference from the batch: {worst:.3g}"
    )


if __name__ == "__main__":
    run_script(main)

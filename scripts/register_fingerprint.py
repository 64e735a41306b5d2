"""The answers of many ``register`` calls, saved, or compared with a saved set: a check that a
change of structure leaves every result as it was.

    git stash; python scripts/register_fingerprint.py --out before.npz; git stash pop
    python scripts/register_fingerprint.py --out after.npz --compare before.npz
    python scripts/register_fingerprint.py --out prepared.npz --compare before.npz --prepared

The calls cover every method of the table, single pairs and batches, one and several
rounds, refinement, masks given by k or a threshold, a cut-off in the clouds' unit, NaN
rows, clouds in millimetres, clouds above the networks' size, and the scene search, on
seeded pairs of the bundled ModelNet40 sample and the Stanford bunny of the real scans. Each
call's transform, masks, rounds and report go into one ``.npz`` (no pickles), and
``--compare`` lists the calls whose arrays differ by more than 1e-9.
"""

from __future__ import annotations

import argparse
import os
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from masknet.cli import run_script


def calls(bunny_path: Path, prepared: bool = False) -> dict[str, Callable]:
    """Name -> a zero-argument call of ``register``; with ``prepared``, every single
    template is given prepared (:func:`masknet.prepare_template`), one per template."""
    from scipy.spatial.transform import Rotation

    from masknet import register

    if prepared:
        register = _with_prepared_templates(register)
    from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
    from masknet.io import read_points

    shapes = load_modelnet40(bundled_sample_path()).points

    def batch(config: PairConfig, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
        pairs = make_test_pairs(shapes, count, config, seed=seed)
        return pairs.template.double().numpy(), pairs.source.double().numpy()

    T, S = batch(PairConfig(), 6, 0)
    far_t, far_s = batch(PairConfig(max_angle_deg=180), 4, 1)
    noisy_t, noisy_s = batch(PairConfig(noise_sigma=0.01, outlier_ratio=0.1), 3, 2)
    out: dict[str, Callable] = {}
    for i in range(3):
        out[f"auto{i}"] = lambda i=i: register(T[i], S[i])
        out[f"auto_mm{i}"] = lambda i=i: register(T[i] * 1000, S[i] * 1000 + 5)
        out[f"noisy{i}"] = lambda i=i: register(noisy_t[i], noisy_s[i])
        out[f"noisy_robust{i}"] = lambda i=i: register(noisy_t[i], noisy_s[i], method="robust")
    for i in range(4):
        out[f"far{i}"] = lambda i=i: register(far_t[i], far_s[i])
    out["auto_it3"] = lambda: register(T[0], S[0], iterations=3)
    out["robust_it2_nearest"] = lambda: register(
        T[1], S[1], method="robust", iterations=2, refine_masks="nearest"
    )
    out["auto_nomask"] = lambda: register(T[2], S[2], use_mask=False)
    methods = ["icp", "pointnetlk", "dcp", "prnet", "pcrnet", "rpmnet", "open3d-icp", "open3d-fgr"]
    for m in methods:
        out[f"{m}_single"] = lambda m=m: register(T[0], S[0], method=m)
        out[f"{m}_nomask"] = lambda m=m: register(T[0], S[0], method=m, use_mask=False)
        out[f"{m}_batch"] = lambda m=m: register(T[:4], S[:4], method=m)
    out["icp_it3"] = lambda: register(T[:3], S[:3], method="icp", iterations=3)
    out["icp_it3_network"] = lambda: register(
        T[0], S[0], method="icp", iterations=3, refine_masks="network"
    )
    out["pointnetlk_it3"] = lambda: register(T[1], S[1], method="pointnetlk", iterations=3)
    out["icp_refine10"] = lambda: register(T[:2], S[:2], method="icp", refine_iterations=10)
    out["icp_threshold"] = lambda: register(T[0], S[0], method="icp", mask_threshold=0.5)
    out["icp_k"] = lambda: register(T[0], S[0], method="icp", k=500)
    out["icp_identity"] = lambda: register(T[0], S[0], method="icp", init="identity")
    out["icp_cut"] = lambda: register(
        T[0] * 100, S[0] * 100, method="icp", max_correspondence_distance=5.0
    )
    out["robust_cut"] = lambda: register(
        T[0] * 100, S[0] * 100, method="robust", max_correspondence_distance=5.0
    )
    nan_t, nan_s = T[0].copy(), S[0].copy()
    nan_t[5], nan_s[7] = np.nan, np.nan
    out["nan_auto"] = lambda: register(nan_t, nan_s, drop_nonfinite=True)
    out["nan_icp"] = lambda: register(nan_t, nan_s, method="icp", drop_nonfinite=True)
    bunny = read_points(bunny_path)
    turn = Rotation.from_euler("xyz", [20, 10, -15], degrees=True).as_matrix()
    part = bunny[bunny[:, 0] < np.quantile(bunny[:, 0], 0.7)] @ turn.T + 0.01
    for m in ["auto", "icp", "pointnetlk", "prnet"]:
        out[f"bunny_{m}"] = lambda m=m: register(bunny, part, method=m)
    out["bunny_it2"] = lambda: register(bunny, part, iterations=2)
    rng = np.random.default_rng(0)
    floor = rng.uniform(-0.4, 0.4, (4000, 3)) * [1, 1, 0.02] + [0, 0, -0.1]
    wall = rng.uniform(-0.4, 0.4, (3000, 3)) * [0.02, 1, 1] + [0.35, 0, 0]
    scene = np.concatenate([part, floor, wall])
    out["scene_auto"] = lambda: register(bunny, scene)
    out["scene_icp"] = lambda: register(bunny, scene, method="icp", scene=True)
    out["scene_robust"] = lambda: register(bunny, scene, method="robust", scene=True)
    return out


def _with_prepared_templates(register: Callable) -> Callable:
    """``register`` given each single template prepared, one prepared template per
    template's values (reused by every call on it)."""
    from masknet import prepare_template

    kept: dict[bytes, object] = {}

    def call(template, source, **options):
        if np.ndim(template) == 2 and np.isfinite(template).all():
            key = np.asarray(template, dtype=np.float64).tobytes()
            if key not in kept:
                kept[key] = prepare_template(template)
            template = kept[key]
        return register(template, source, **options)

    return call


FIELDS = ("transform", "mask", "source_mask", "correspondence_inliers")


def record(results: dict, name: str, call: Callable) -> None:
    """The call's arrays into ``results`` under ``name/...``; a refusal as its message."""
    from masknet.errors import MaskNetError

    try:
        result = call()
    except MaskNetError as exc:
        results[f"{name}/error"] = np.array(str(exc))
        return
    for field in FIELDS:
        value = getattr(result, field)
        if value is not None:
            results[f"{name}/{field}"] = np.asarray(value)
    results[f"{name}/rounds"] = np.asarray(result.rounds)
    results[f"{name}/method"] = np.array(result.method)
    for key, value in result.info.items():
        array = np.asarray(value)
        if array.dtype != object:
            results[f"{name}/info/{key}"] = array


def differences(before: dict, after: dict) -> list[str]:
    """One line per key that is missing on one side or differs by more than 1e-9."""
    lines = [f"{key}: only in one set" for key in sorted(set(before) ^ set(after))]
    for key in sorted(set(before) & set(after)):
        a, b = before[key], after[key]
        if a.shape != b.shape:
            lines.append(f"{key}: shape {a.shape} against {b.shape}")
        elif a.dtype.kind in "fc":
            finite = np.isfinite(a) & np.isfinite(b)
            if not np.array_equal(np.isfinite(a), np.isfinite(b)):
                lines.append(f"{key}: non-finite entries differ")
            elif finite.any() and np.abs(a - b)[finite].max() > 1e-9:
                lines.append(f"{key}: differs by {np.abs(a - b)[finite].max():.3g}")
        elif not np.array_equal(a, b):
            lines.append(f"{key}: differs")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, help="the .npz to write")
    parser.add_argument("--compare", help="a .npz written before: list what differs")
    parser.add_argument(
        "--prepared", action="store_true", help="give every single template prepared once"
    )
    parser.add_argument(
        "--bunny",
        default=str(
            Path(__file__).resolve().parents[1] / "../shared/data/scans/bun_zipper_res3.ply"
        ),
        help="the Stanford bunny (default: ../shared/data/scans/bun_zipper_res3.ply)",
    )
    args = parser.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # Open3D's RANSAC repeats on one thread
    warnings.simplefilter("ignore")
    results: dict[str, np.ndarray] = {}
    todo = calls(Path(args.bunny), args.prepared)
    for name, call in todo.items():
        record(results, name, call)
    np.savez(args.out, **results)
    print(f"{len(todo)} calls, {len(results)} arrays -> {args.out}")
    if args.compare:
        with np.load(args.compare, allow_pickle=False) as saved:
            before = {key: saved[key] for key in saved.files}
        lines = differences(before, results)
        print("\n".join(lines) if lines else "every array is as it was")
        if lines:
            raise SystemExit(1)


if __name__ == "__main__":
    run_script(main)

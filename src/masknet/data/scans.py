"""Real scans as training and test data: crops of large scans, cut into sensor-like pairs.

This is the paper's S3DIS protocol on any scan: a region of a large scan (the
``crop_points`` points nearest a random centre) is normalised to unit radius, and
:func:`masknet.data.views.make_view_pair` cuts a template and an independently
sampled, visibility-limited, moved and noisy source from it. The ground truth comes
from geometry alone, so any folder of unlabelled scans is training data.

A folder is read once (:func:`load_scans`): every ``.ply``, ``.pcd``, ``.xyz``, ``.txt``,
``.csv``, ``.npy`` or ``.bin`` file in it, with non-finite rows dropped. An unreadable
file, or one with too few points, gets one warning line naming it, and the others are
used. Each scan keeps a fixed random subset of at most ``max_points`` points (seeded by
its name), in a KD-tree, so a crop costs one query.
"""

from __future__ import annotations

import sys
import warnings
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from masknet.data.pairs import Pairs, derive_seed
from masknet.data.views import ViewConfig, make_view_pairs, normalize_cloud
from masknet.errors import MaskNetError, MaskNetWarning

__all__ = [
    "SCAN_EXTENSIONS",
    "Scan",
    "ScanCropConfig",
    "crop_scan",
    "default_validation_scans",
    "iterate_scan_pairs",
    "load_scans",
    "make_scan_test_pairs",
    "split_scans",
]

SCAN_EXTENSIONS = (".ply", ".pcd", ".xyz", ".txt", ".csv", ".npy", ".bin")


@dataclass
class Scan:
    """One real scan: ``points`` (P, 3) float32 in the scan's units."""

    name: str
    points: np.ndarray

    def __len__(self) -> int:
        return len(self.points)


@dataclass(frozen=True)
class ScanCropConfig:
    """How crops are cut from a scan.

    crop_points: (min, max) points in a crop, drawn uniformly per crop: the crop is that
        many of the scan's (subsampled) points nearest a random centre. Larger crops
        cover more of the scene at a lower density.
    max_points: each scan keeps at most this many points (a fixed random subset).
    """

    crop_points: tuple[int, int] = (2048, 6144)
    max_points: int = 65536

    def __post_init__(self) -> None:
        lo, hi = self.crop_points
        if not 16 <= lo <= hi:
            raise ValueError(f"crop_points must be (min, max) with 16 <= min <= max, got {lo, hi}")


def _warn(message: str) -> None:
    print(f"masknet: warning: {message}", file=sys.stderr, flush=True)


def load_scans(
    folder: str | Path, min_points: int = 1024, max_points: int = 65536, quiet: bool = False
) -> list[Scan]:
    """Read every scan file in ``folder`` (sorted by name; not recursive).

    Files that cannot be read, or hold fewer than ``min_points`` finite points, are
    skipped with one warning line each (unless ``quiet``).

    Raises:
        MaskNetError: the folder is missing, or no file in it is a usable scan.
    """
    from masknet.io import read_points

    root = Path(folder)
    if not root.is_dir():
        what = "a file, not a folder of scans" if root.exists() else "no such folder of scans"
        raise MaskNetError(f"{root}: {what}")
    files = sorted(f for f in root.iterdir() if f.suffix.lower() in SCAN_EXTENSIONS)
    scans = []
    for path in files:
        try:
            # A file that is skipped says so in one line; its cloud warnings would only
            # add to that.
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", MaskNetWarning)
                points = read_points(path, drop_nonfinite=True)
        except MaskNetError as exc:
            if not quiet:
                _warn(f"{exc}; skipped")
            continue
        if len(points) < min_points:
            if not quiet:
                _warn(f"{path}: only {len(points)} points, fewer than {min_points}; skipped")
            continue
        if len(points) > max_points:
            rng = np.random.default_rng(zlib.crc32(path.name.encode()))
            points = points[np.sort(rng.choice(len(points), max_points, replace=False))]
        with np.errstate(over="ignore"):
            points = points.astype(np.float32)
        problem = _implausible(points)
        if problem:
            if not quiet:
                _warn(f"{path}: {problem}; skipped")
            continue
        scans.append(Scan(path.stem, points))
    if not scans:
        raise MaskNetError(
            f"{root}: no usable scan (need {', '.join(SCAN_EXTENSIONS)} files "
            f"with at least {min_points} points)"
        )
    return scans


def _implausible(points: np.ndarray) -> str | None:
    """Why (P, 3) float32 points cannot be a scan, or None."""
    if not np.isfinite(points).all():
        return "coordinates beyond the float32 range"
    extent = points.max(0) - points.min(0)
    if np.count_nonzero(extent > 1e-6 * max(float(extent.max()), 1e-30)) < 2 or not extent.max():
        return "all points identical or on one line"
    return None


def default_validation_scans(names: Sequence[str]) -> list[str]:
    """The fixed validation list when none is given: every fifth scan in name order,
    starting with the third (at least one, and never all of them)."""
    names = sorted(names)
    if len(names) < 2:
        return []
    return [name for i, name in enumerate(names) if i % 5 == 2] or [names[-1]]


def split_scans(
    scans: Sequence[Scan], validation: Sequence[str] | None
) -> tuple[list[Scan], list[Scan]]:
    """(training scans, validation scans): whole scans held out by name (file stem).

    ``validation`` None uses :func:`default_validation_scans`.

    Raises:
        MaskNetError: a validation name is not among the scans, or nothing is left to train.
    """
    names = [s.name for s in scans]
    held = default_validation_scans(names) if validation is None else list(validation)
    unknown = sorted(set(held) - set(names))
    if unknown:
        raise MaskNetError(
            f"validation scans not found: {', '.join(unknown)} (scans: {', '.join(names)})"
        )
    train = [s for s in scans if s.name not in held]
    if not train:
        raise MaskNetError("every scan is held out for validation; none is left to train on")
    return train, [s for s in scans if s.name in held]


def crop_scan(scan: Scan, crop: ScanCropConfig, rng: np.random.Generator) -> np.ndarray:
    """A unit-radius crop (C, 3) float32 of ``scan``: the C points nearest a random point."""
    lo, hi = crop.crop_points
    count = min(int(rng.integers(lo, hi + 1)), len(scan))
    centre = scan.points[rng.integers(len(scan))]
    # One query point: a distance per point and a partial sort beat building a tree.
    d2 = ((scan.points.astype(np.float64) - centre) ** 2).sum(1)
    near = np.argpartition(d2, count - 1)[:count] if count < len(d2) else np.arange(len(d2))
    return normalize_cloud(scan.points[near[np.argsort(d2[near], kind="stable")]])


def _crop_config_for(view: ViewConfig, crop: ScanCropConfig) -> ScanCropConfig:
    lo, hi = crop.crop_points
    need = view.min_cloud_points
    return ScanCropConfig((max(lo, need), max(hi, need)), crop.max_points)


def iterate_scan_pairs(
    scans: Sequence[Scan],
    view: ViewConfig,
    crop: ScanCropConfig,
    num_batches: int,
    batch_size: int,
    seed: int,
    epoch: int = 0,
) -> Iterator[Pairs]:
    """``num_batches`` batches of fresh view pairs from crops of ``scans``.

    Each pair picks a scan uniformly (so small scans count as much as large ones),
    then a crop; deterministic in (seed, epoch, batch).
    """
    crop = _crop_config_for(view, crop)
    for i in range(num_batches):
        rng = np.random.default_rng(derive_seed(seed, epoch, i + 1, 0x5CA9))
        picks = rng.integers(len(scans), size=batch_size)
        yield make_view_pairs([crop_scan(scans[j], crop, rng) for j in picks], view, rng)


def make_scan_test_pairs(
    scans: Sequence[Scan],
    pairs_per_scan: int,
    view: ViewConfig,
    crop: ScanCropConfig | None = None,
    seed: int = 0,
) -> tuple[Pairs, list[str]]:
    """A fixed, seeded test set: ``pairs_per_scan`` pairs from each scan, in scan order.

    Returns the pairs and, per pair, the name of the scan it was cut from.
    """
    crop = _crop_config_for(view, crop or ScanCropConfig())
    batches, names = [], []
    for k, scan in enumerate(scans):
        rng = np.random.default_rng(derive_seed(seed, k, zlib.crc32(scan.name.encode())))
        clouds = [crop_scan(scan, crop, rng) for _ in range(pairs_per_scan)]
        batches.append(make_view_pairs(clouds, view, rng))
        names += [scan.name] * pairs_per_scan
    return Pairs(*(torch.cat(parts) for parts in zip(*batches, strict=True))), names

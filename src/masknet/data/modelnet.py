"""ModelNet40 readers: one entry point, :func:`load_modelnet40`, for four layouts.

* the official PointNet HDF5 release: a folder ``modelnet40_ply_hdf5_2048/`` with
  ``ply_data_{train,test}*.h5`` and ``shape_names.txt`` (the first 1,024 of the
  2,048 points are used, as PointNet does);
* a folder of per-shape ``.npy`` files: ``<class>/{train,test}/*.npy``;
* the compact ``.npz`` of int16 points (``modelnet40_1024_int16.npz``, and the
  sample bundled with this package), with keys ``{train,test}_points`` (S, N, 3)
  int16, ``scale`` (float; coordinates = points * scale), ``{train,test}_labels``
  (S,) int, optional ``{train,test}_names`` (S,) str and ``shape_names`` (40,) str;
* raw ``.off`` meshes: ``<class>/{train,test}/*.off``, surface-sampled with trimesh.

The HDF5 and ``.off`` layouts need h5py and trimesh (``pip install 'masknet[data]'``).

Every shape is returned centred on its bounding-box centre and scaled to a
largest radius of 1.0, the normalisation of the bundled data.
"""

from __future__ import annotations

import os
import zipfile
import zlib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Literal

import numpy as np

from masknet._extras import need
from masknet.errors import MaskNetError

__all__ = [
    "PointCloudSet",
    "load_modelnet40",
    "bundled_sample_path",
    "resolve_data_path",
    "CATEGORY_SUBSETS",
]

Split = Literal["train", "test"]
CATEGORY_SUBSETS = ("all", "seen", "unseen")

DOWNLOAD_HINT = (
    "download the PointNet release https://shapenet.cs.stanford.edu/media/modelnet40_ply_hdf5_2048.zip, "
    "unzip it and pass the folder with --data (or set MASKNET_DATA); a ModelNet40 .npz, a folder of "
    "<class>/{train,test}/*.npy or of <class>/{train,test}/*.off meshes also works"
)


@dataclass
class PointCloudSet:
    """Shapes of one split.

    points: (S, N, 3) float32, each shape centred and scaled to unit radius.
    labels: (S,) int64 indices into ``shape_names``.
    names: (S,) shape identifiers, e.g. ``airplane_0627``.
    shape_names: the 40 category names, alphabetical.
    """

    points: np.ndarray
    labels: np.ndarray
    names: np.ndarray
    shape_names: list[str]

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, categories: str) -> PointCloudSet:
        """``"all"``, ``"seen"`` (first 20 categories, alphabetical) or ``"unseen"`` (last 20)."""
        if categories == "all":
            return self
        if categories not in CATEGORY_SUBSETS:
            raise MaskNetError(f"categories must be one of {CATEGORY_SUBSETS}, got {categories!r}")
        half = len(self.shape_names) // 2
        keep = self.labels < half if categories == "seen" else self.labels >= half
        return self.select(np.flatnonzero(keep))

    def select(self, index: np.ndarray) -> PointCloudSet:
        return PointCloudSet(
            self.points[index], self.labels[index], self.names[index], self.shape_names
        )


def bundled_sample_path() -> Path:
    """The small ModelNet40 test-split sample shipped inside the package."""
    return Path(str(resources.files("masknet") / "resources" / "modelnet40_sample.npz"))


def resolve_data_path(path: str | os.PathLike | None) -> Path:
    """``path``, else ``$MASKNET_DATA``; a clear error if neither names something that exists."""
    chosen = path if path is not None else (os.environ.get("MASKNET_DATA") or None)
    if chosen is None:
        raise MaskNetError(f"no ModelNet40 data given: {DOWNLOAD_HINT}")
    resolved = Path(chosen).expanduser()
    if not resolved.exists():
        raise MaskNetError(f"{resolved}: no such file or folder; {DOWNLOAD_HINT}")
    return resolved


def normalize_unit_sphere(points: np.ndarray) -> np.ndarray:
    """Centre (S, N, 3) shapes on their bounding-box centres and scale to radius 1."""
    centre = (points.max(1, keepdims=True) + points.min(1, keepdims=True)) / 2
    centred = points - centre
    radius = np.linalg.norm(centred, axis=-1).max(1)[:, None, None]
    return (centred / np.maximum(radius, 1e-12)).astype(np.float32)


def load_modelnet40(
    path: str | os.PathLike | None = None, split: Split = "test", num_points: int = 1024
) -> PointCloudSet:
    """Load one split of ModelNet40 from any supported layout (detected from ``path``).

    Args:
        path: file or folder; ``None`` reads ``$MASKNET_DATA``.
        split: ``"train"`` or ``"test"``.
        num_points: points per shape (the first ``num_points`` stored, or the number
            sampled from meshes).
    """
    if split not in ("train", "test"):
        raise MaskNetError(f"split must be 'train' or 'test', got {split!r}")
    root = resolve_data_path(path)
    if root.is_file():
        if root.suffix != ".npz":
            raise MaskNetError(f"{root}: not a ModelNet40 .npz file; {DOWNLOAD_HINT}")
        data = _load_npz(root, split)
    else:
        data = _load_folder(root, split, num_points)
    if data.points.ndim != 3 or data.points.shape[-1] != 3:
        raise MaskNetError(
            f"{root}: expected shapes of (N, 3) points, got array {data.points.shape}"
        )
    if len(data.points) == 0:
        raise MaskNetError(f"{root}: the {split} split holds no shapes")
    if not np.isfinite(data.points).all():
        bad = int((~np.isfinite(data.points)).any(axis=(1, 2)).sum())
        raise MaskNetError(f"{root}: {bad} shapes contain NaN or inf coordinates")
    if data.points.shape[1] < num_points:
        raise MaskNetError(
            f"{root}: shapes have {data.points.shape[1]} points, fewer than {num_points}"
        )
    data.points = normalize_unit_sphere(data.points[:, :num_points])
    return data


def _load_folder(root: Path, split: Split, num_points: int) -> PointCloudSet:
    for candidate in (root, root / "modelnet40_ply_hdf5_2048"):
        if list(candidate.glob(f"ply_data_{split}*.h5")):
            return _load_hdf5(candidate, split)
    npz = sorted(root.glob("*.npz"))
    if len(npz) == 1:
        return _load_npz(npz[0], split)
    # Classes come from both splits so that labels agree between train and test.
    class_dirs = sorted(
        d for d in root.iterdir() if (d / "train").is_dir() or (d / "test").is_dir()
    )
    if any((d / split).is_dir() for d in class_dirs):
        for kind in ("npy", "off"):
            if any(_has_file(d / split, kind) for d in class_dirs):
                return _load_per_shape(root, class_dirs, split, kind, num_points)
    raise MaskNetError(f"{root}: no ModelNet40 data found for split {split!r}; {DOWNLOAD_HINT}")


def _has_file(folder: Path, kind: str) -> bool:
    return next(folder.glob(f"*.{kind}"), None) is not None


def _load_npz(path: Path, split: Split) -> PointCloudSet:
    try:
        with np.load(path, allow_pickle=False) as data:
            points = data[f"{split}_points"]
            scale = float(data["scale"]) if "scale" in data else 1.0
            labels = data[f"{split}_labels"].astype(np.int64)
            names = (
                data[f"{split}_names"] if f"{split}_names" in data else np.array([""] * len(points))
            )
            shape_names = [str(s) for s in data["shape_names"]]
    except KeyError as exc:
        raise MaskNetError(
            f"{path}: missing array {exc.args[0]!r}; not a ModelNet40 .npz"
        ) from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise MaskNetError(f"{path}: unreadable or truncated .npz ({exc})") from None
    return PointCloudSet(points.astype(np.float32) * np.float32(scale), labels, names, shape_names)


def _load_hdf5(folder: Path, split: Split) -> PointCloudSet:
    h5py = need("h5py", "data", f"{folder}: reading HDF5 shards")

    names_file = folder / "shape_names.txt"
    if not names_file.exists():
        raise MaskNetError(f"{names_file}: missing (it lists the 40 category names)")
    shape_names = [line.strip() for line in names_file.read_text().splitlines() if line.strip()]
    points, labels = [], []
    for file in sorted(folder.glob(f"ply_data_{split}*.h5")):
        try:
            with h5py.File(file, "r") as h5:
                points.append(np.asarray(h5["data"], dtype=np.float32))
                labels.append(np.asarray(h5["label"]).reshape(-1).astype(np.int64))
        except (OSError, KeyError) as exc:
            raise MaskNetError(f"{file}: unreadable HDF5 shard ({exc})") from None
    if not points:
        raise MaskNetError(f"{folder}: no ply_data_{split}*.h5 shards")
    all_labels = np.concatenate(labels)
    if all_labels.min() < 0 or all_labels.max() >= len(shape_names):
        raise MaskNetError(
            f"{folder}: labels outside the {len(shape_names)} names of shape_names.txt"
        )
    names = np.array([f"{shape_names[c]}_{i}" for i, c in enumerate(all_labels)])
    return PointCloudSet(np.concatenate(points), all_labels, names, shape_names)


def _load_per_shape(
    root: Path, class_dirs: list[Path], split: Split, kind: str, num_points: int
) -> PointCloudSet:
    shape_names = [d.name for d in class_dirs]
    points, labels, names = [], [], []
    for label, folder in enumerate(class_dirs):
        for file in sorted((folder / split).glob(f"*.{kind}")):
            cloud = _read_npy_shape(file) if kind == "npy" else _sample_mesh(file, num_points)
            if len(cloud) < num_points:
                raise MaskNetError(f"{file}: {len(cloud)} points, fewer than {num_points}")
            points.append(cloud[:num_points, :3])
            labels.append(label)
            names.append(file.stem)
    if not points:
        raise MaskNetError(f"{root}: no .{kind} shapes in the {split} split")
    return PointCloudSet(
        np.stack(points).astype(np.float32), np.array(labels), np.array(names), shape_names
    )


def _read_npy_shape(file: Path) -> np.ndarray:
    try:
        cloud = np.load(file, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise MaskNetError(f"{file}: unreadable .npy ({exc})") from None
    if cloud.ndim != 2 or cloud.shape[1] < 3:
        raise MaskNetError(f"{file}: expected an (N, 3) array, got shape {cloud.shape}")
    return cloud


def _sample_mesh(file: Path, num_points: int) -> np.ndarray:
    trimesh = need("trimesh", "data", f"{file}: sampling meshes")

    try:
        mesh = trimesh.load(file, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for malformed files
        raise MaskNetError(f"{file}: unreadable mesh ({exc})") from None
    if len(mesh.faces) == 0:
        raise MaskNetError(f"{file}: mesh has no faces")
    # A fixed seed per file keeps the sampled dataset reproducible.
    seed = zlib.crc32(file.stem.encode())
    points, _ = trimesh.sample.sample_surface(mesh, num_points, seed=seed)
    return np.asarray(points)

"""Reading and writing point clouds, masks and text files, with one-line errors.

Every failure caused by the user's input (a missing file, an unknown extension, a
truncated or corrupt file, a cloud with too few or non-finite points) raises
:class:`~masknet.errors.MaskNetError` whose message names the file and the problem,
e.g. ``scan.ply: 12 rows contain NaN or inf``.

**Formats** (chosen by extension, case-insensitive):

* ``.ply``, ``.pcd``: Open3D (``.ply`` falls back to trimesh, of the ``data`` extra,
  when Open3D does not import). Note that ``.pcd`` files written by Open3D store
  float32 coordinates.
* ``.xyz``, ``.txt``, ``.csv``: text, one point per line, whitespace or comma
  separated; the first 3 columns are x, y, z (extra columns such as normals or
  colours are ignored); ``#`` starts a comment; one header line is skipped.
* ``.npy``: a numeric 2-D array with at least 3 columns; the first 3 are used.
* ``.bin``: KITTI velodyne scans, float32 (x, y, z, intensity) records (read only).

**Open3D quirks handled here.** Open3D does not raise on bad files: it prints a
warning (through Python's ``sys.stdout``) and returns either an empty cloud (garbage,
empty or missing files) or, for a truncated binary PLY, a cloud with the full header
count whose tail is uninitialised memory. Reads therefore capture Open3D's output
(which also keeps its chatter, and the C library RPly's stderr lines, out of the
user's way) and treat any reported failure, or zero points, as an error.

**Writes are atomic**: data goes to a temporary file in the target's directory
(keeping the extension, since Open3D picks the format from it) and is then moved
into place with :func:`os.replace`, so a failure never leaves a partial file.

Open3D is optional and slow to import, so it is imported lazily by
:func:`require_open3d` (:mod:`masknet._open3d`, with the capture of its output).
"""

from __future__ import annotations

import contextlib
import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from masknet._atomic import atomic_target, write_text_atomic
from masknet._extras import need
from masknet._open3d import captured_output, has_open3d, open3d_failure, require_open3d
from masknet.errors import MaskNetError, first_line
from masknet.io_checks import check_cloud, check_pcd_body, check_ply_body

__all__ = [
    "SUPPORTED_READ",
    "SUPPORTED_WRITE",
    "PointAttributes",
    "PointsRead",
    "read_point_attributes",
    "read_points",
    "read_points_with_rows",
    "write_points",
    "write_mask",
    "write_text_atomic",
    "has_open3d",
    "require_open3d",
]

SUPPORTED_READ = (".ply", ".pcd", ".xyz", ".txt", ".csv", ".npy", ".bin")
SUPPORTED_WRITE = (".ply", ".pcd", ".xyz", ".txt", ".npy")

PathLike = str | os.PathLike

# --------------------------------------------------------------------------- reading


class PointsRead(NamedTuple):
    """A cloud read from a file and where its points lie in the file
    (:func:`read_points_with_rows`): points (N, 3) float64, and rows (P,) bool over the
    file's P rows, True for the N kept, so that per-point outputs can be laid out row for
    row."""

    points: np.ndarray
    rows: np.ndarray


def read_points(
    path: PathLike, drop_nonfinite: bool = False, *, return_rows: bool | None = None
) -> np.ndarray:
    """Read a point cloud file into a float64 array (N, 3), N >= 3, all finite.

    Args:
        path: a ``.ply``, ``.pcd``, ``.xyz``, ``.txt``, ``.csv``, ``.npy`` or ``.bin``
            file (see the module docstring for the formats).
        drop_nonfinite: drop rows containing NaN or inf instead of raising.
        return_rows: deprecated (it changed the return type); use
            :func:`read_points_with_rows`, which also says which of the file's rows were
            kept.

    Raises:
        MaskNetError: the file is missing, a directory, of an unsupported type,
            unreadable, truncated or corrupt; or it holds no points, fewer than 3,
            an array of the wrong shape, or (unless ``drop_nonfinite``) NaN/inf rows.
    """
    read = read_points_with_rows(path, drop_nonfinite=drop_nonfinite)
    if return_rows is not None:
        warnings.warn(
            "read_points(..., return_rows=...) is deprecated and will be removed in the next "
            "release; use read_points_with_rows(path), which returns (points, rows)",
            DeprecationWarning,
            stacklevel=2,
        )
        if return_rows:
            return tuple(read)
    return read.points


def read_points_with_rows(path: PathLike, *, drop_nonfinite: bool = False) -> PointsRead:
    """:func:`read_points`, and which of the file's rows the points are:
    ``PointsRead(points, rows)``, points (N, 3) float64 and rows (P,) bool over the file's
    P rows, True for those kept (all of them unless ``drop_nonfinite`` dropped some).
    Raises as :func:`read_points` does."""
    name = os.fspath(path)
    p = Path(name)
    if not p.exists():
        raise MaskNetError(f"{name}: no such file")
    if p.is_dir():
        raise MaskNetError(f"{name}: is a directory, not a point cloud file")
    ext = p.suffix.lower()
    reader = _READERS.get(ext)
    if reader is None:
        raise MaskNetError(
            f"{name}: unsupported extension {ext or '(none)'!r} "
            f"(supported: {', '.join(SUPPORTED_READ)})"
        )
    with contextlib.suppress(OSError):
        if p.stat().st_size == 0:
            raise MaskNetError(f"{name}: empty file (no points)")
    try:
        points = reader(name)
    except MaskNetError:
        raise
    except OSError as exc:
        raise MaskNetError(f"{name}: cannot read file ({exc.strerror or exc})") from exc
    points, rows = check_cloud(points, name, drop_nonfinite)
    return PointsRead(points, rows)


class PointAttributes(NamedTuple):
    """What a ``.ply``/``.pcd`` file holds beside its points, row for row with the file:
    colors (P, 3) in [0, 1] and normals (P, 3), each None where the file has none."""

    colors: np.ndarray | None = None
    normals: np.ndarray | None = None

    def take(self, rows: np.ndarray) -> PointAttributes:
        """The attributes of ``rows`` (a bool mask or indices over the points)."""
        return PointAttributes(*(None if a is None else a[rows] for a in self))

    def turned(self, rotation: np.ndarray) -> PointAttributes:
        """Normals turned by ``rotation`` (3, 3), as the points are moved."""
        return self._replace(normals=None if self.normals is None else self.normals @ rotation.T)


def read_point_attributes(path: PathLike, for_output: PathLike | None = None) -> PointAttributes:
    """Colours and normals of a ``.ply``/``.pcd`` file (read by Open3D), row for row with
    :func:`read_points_with_rows`'s rows; none for other formats, or
    when Open3D is not available. Outputs pass them on, so nothing the user had is lost.
    ``for_output``: the file they are for; none (and no read) when it cannot hold them."""
    name = os.fspath(path)
    fmt = Path(name).suffix.lower().lstrip(".")
    holds = for_output is None or Path(for_output).suffix.lower() in (".ply", ".pcd")
    if fmt not in ("ply", "pcd") or not holds:
        return PointAttributes()
    try:
        o3d = require_open3d(f"{name}: reading colours and normals")
    except MaskNetError:
        return PointAttributes()
    with captured_output(), o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        cloud = o3d.io.read_point_cloud(
            name, format=fmt, remove_nan_points=False, remove_infinite_points=False
        )
    return PointAttributes(
        np.asarray(cloud.colors, dtype=np.float64) if cloud.has_colors() else None,
        np.asarray(cloud.normals, dtype=np.float64) if cloud.has_normals() else None,
    )


def _read_open3d(name: str, fmt: str) -> np.ndarray:
    """Read ``.ply``/``.pcd`` with Open3D; a reported failure or 0 points is an error."""
    feature = f"{name}: reading .{fmt} files"
    if fmt == "ply":
        try:
            o3d = require_open3d(feature)
        except MaskNetError:
            return _read_trimesh(name)
    else:
        o3d = require_open3d(feature)
    verbosity = o3d.utility.VerbosityLevel.Warning  # so that failures are reported
    try:
        with captured_output() as out, o3d.utility.VerbosityContextManager(verbosity):
            cloud = o3d.io.read_point_cloud(
                name, format=fmt, remove_nan_points=False, remove_infinite_points=False
            )
    except MemoryError as exc:  # Open3D allocating what a corrupt header declares
        raise MaskNetError(
            f"{name}: truncated or corrupt .{fmt} file (its header asks for "
            "more memory than there is)"
        ) from exc
    failure = open3d_failure(out.getvalue())
    if failure is not None:
        raise MaskNetError(f"{name}: unreadable, truncated or corrupt .{fmt} file ({failure})")
    points = np.asarray(cloud.points, dtype=np.float64)
    if len(points) == 0:
        raise MaskNetError(f"{name}: no points (empty, or not a valid .{fmt} file)")
    return points.reshape(-1, 3)


def _read_trimesh(name: str) -> np.ndarray:
    """Fallback PLY reader (vertices of whatever trimesh loads)."""
    trimesh = need("trimesh", "data", f"{name}: reading .ply files without Open3D")

    try:
        obj = trimesh.load(name)
    except Exception as exc:
        reason = first_line(str(exc)) or type(exc).__name__
        raise MaskNetError(
            f"{name}: unreadable, truncated or corrupt .ply file ({reason})"
        ) from exc
    if isinstance(obj, trimesh.Scene):
        parts = [np.asarray(g.vertices) for g in obj.geometry.values() if hasattr(g, "vertices")]
        return np.concatenate(parts) if parts else np.empty((0, 3))
    return np.asarray(getattr(obj, "vertices", np.empty((0, 3))))


def _read_ply(name: str) -> np.ndarray:
    if os.path.isfile(name):
        check_ply_body(name)
    return _read_open3d(name, "ply")


def _read_pcd(name: str) -> np.ndarray:
    if os.path.isfile(name):
        check_pcd_body(name)
    return _read_open3d(name, "pcd")


def _read_text(name: str) -> np.ndarray:
    """Whitespace- or comma-separated text; one header line is tolerated."""
    try:
        with open(name, encoding="utf-8") as f:
            lines = [line.replace(",", " ") for line in f]
    except UnicodeDecodeError as exc:
        raise MaskNetError(f"{name}: not a text file (cannot decode as UTF-8)") from exc

    def load(rows: list[str]) -> np.ndarray:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data"
            return np.loadtxt(rows, dtype=np.float64, comments="#", ndmin=2)

    try:
        return load(lines)
    except ValueError as exc:
        first = next((i for i, s in enumerate(lines) if s.split("#")[0].strip()), None)
        if first is not None:  # maybe a header such as "x,y,z"
            with contextlib.suppress(ValueError):
                rows = load(lines[first + 1 :])
                if rows.size:  # a header over numbers, not a file of words
                    return rows
        reason = first_line(str(exc))
        raise MaskNetError(f"{name}: cannot parse as numbers ({reason})") from exc


def _read_npy(name: str) -> np.ndarray:
    with open(name, "rb") as head:
        magic = head.read(6)
    # Without NumPy's magic (or a zip's), np.load would take the file for a pickle and
    # suggest allow_pickle, which is never the fix here.
    if magic != b"\x93NUMPY" and not magic.startswith(b"PK\x03\x04"):
        raise MaskNetError(f"{name}: not a .npy file (no NumPy header)")
    try:
        arr = np.load(name, allow_pickle=False)
    except (OSError, MemoryError):
        raise
    except Exception as exc:  # a corrupt header fails in numpy's parser in many ways
        reason = first_line(str(exc)) or type(exc).__name__
        raise MaskNetError(f"{name}: not a valid, readable .npy file ({reason})") from exc
    if not isinstance(arr, np.ndarray):  # an .npz archive under a .npy name
        with contextlib.suppress(Exception):
            arr.close()
        raise MaskNetError(f"{name}: an .npz archive, not a single .npy array")
    return arr


def _read_kitti_bin(name: str) -> np.ndarray:
    size = os.path.getsize(name)
    if size % 16:
        raise MaskNetError(
            f"{name}: size {size} bytes is not a multiple of 16, so not a KITTI .bin "
            "scan of float32 (x, y, z, intensity) records (truncated?)"
        )
    return np.fromfile(name, dtype=np.float32).reshape(-1, 4)[:, :3]


_READERS: dict[str, Callable[[str], np.ndarray]] = {
    ".ply": _read_ply,
    ".pcd": _read_pcd,
    ".xyz": _read_text,
    ".txt": _read_text,
    ".csv": _read_text,
    ".npy": _read_npy,
    ".bin": _read_kitti_bin,
}


# --------------------------------------------------------------------------- writing

# The atomic-write helper lives in masknet._atomic; this name stays for older imports.
_atomic_target = atomic_target


def write_mask(path: PathLike, mask: np.ndarray) -> None:
    """Write a mask (N,) as text, one ``0`` or ``1`` per line, atomically.

    ``mask`` may be Boolean or numeric with values 0 and 1 only.
    """
    name = os.fspath(path)
    mask = np.asarray(mask)
    if mask.ndim != 1:
        raise MaskNetError(f"{name}: a mask must be 1-D, got shape {tuple(mask.shape)}")
    if mask.dtype != np.bool_:
        if mask.dtype.kind not in "iuf" or not np.isin(mask, (0, 1)).all():
            raise MaskNetError(f"{name}: a mask must hold only 0 and 1 (or booleans)")
        mask = mask.astype(bool)
    write_text_atomic(name, "".join("1\n" if m else "0\n" for m in mask.tolist()))


def write_points(
    path: PathLike,
    points: np.ndarray,
    colors: np.ndarray | None = None,
    normals: np.ndarray | None = None,
) -> None:
    """Write points (N, 3) to ``path``, format by extension, atomically.

    ``.ply``/``.pcd`` via Open3D (``.pcd`` stores float32), with ``colors`` (N, 3) in
    [0, 1] and ``normals`` (N, 3) where given; ``.xyz``/``.txt`` as text with full
    float64 precision, ``.npy`` as a float64 array (these two hold points only). Parent
    directories are created. An unsupported extension raises before anything is written.
    NaN rows are written as they are (organised depth clouds hold them); ``read_points``
    reads them back with ``drop_nonfinite=True``.
    """
    name = os.fspath(path)
    if Path(name).is_dir():
        raise MaskNetError(f"{name}: is a directory, not a file")
    ext = Path(name).suffix.lower()
    if ext not in SUPPORTED_WRITE:
        raise MaskNetError(
            f"{name}: cannot write extension {ext or '(none)'!r} "
            f"(supported: {', '.join(SUPPORTED_WRITE)})"
        )
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise MaskNetError(f"{name}: expected points of shape (N, 3), got {tuple(points.shape)}")
    o3d = None
    if ext in (".ply", ".pcd"):
        if len(points) == 0:
            raise MaskNetError(f"{name}: cannot write an empty cloud as {ext} (Open3D refuses)")
        o3d = require_open3d(f"{name}: writing {ext} files")
    with atomic_target(name, suffix=ext) as tmp:
        if o3d is not None:
            from masknet.geometry.open3d_clouds import to_open3d

            cloud = to_open3d(points, normals=normals, colors=colors)
            verbosity = o3d.utility.VerbosityLevel.Warning
            with captured_output() as out, o3d.utility.VerbosityContextManager(verbosity):
                ok = o3d.io.write_point_cloud(tmp, cloud)
            if not ok:
                reason = open3d_failure(out.getvalue()) or "Open3D reported failure"
                raise MaskNetError(f"{name}: cannot write ({reason})")
        elif ext == ".npy":
            np.save(tmp, points)
        else:
            np.savetxt(tmp, points, fmt="%.17g")

"""The one set of checks of point clouds, for files and for arrays alike.

:func:`check_cloud` decides for :func:`masknet.io.read_points` (the CLI's every input)
and for :func:`masknet.register` and the other entry points of the API: numbers only, an
(N, 3) array (a transposed (3, N) one is named as such), NaN/inf rows counted (dropped
on request), at least 3 points, coordinates small enough that squared distances do not
overflow float32, and a 3-D extent; very few points, or one point far out, give a
:class:`~masknet.errors.MaskNetWarning`. The PLY and PCD checks compare a header with
its body.
"""

from __future__ import annotations

import os

import numpy as np

from masknet.errors import MaskNetError, warn
from masknet.geometry.clouds import MIN_POINTS
from masknet.geometry.open3d_clouds import from_open3d

__all__ = [
    "FEW_POINTS",
    "FLOAT32_MAX",
    "LARGEST_COORDINATE",
    "check_cloud",
    "check_geometry",
    "check_pcd_body",
    "check_ply_body",
    "over_rows",
]

FLOAT32_MAX = float(np.finfo(np.float32).max)
FEW_POINTS = 10  # at most this many points: registration is unreliable, say so
# Beyond this, squared distances of float32 coordinates (the networks', the KD-trees')
# overflow: sqrt(3.4e38) is 1.8e19; keep a margin for sums of squares and products.
LARGEST_COORDINATE = 1e15


def over_rows(mask: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """A mask (K,) over the rows :func:`check_cloud` kept, laid out over all the input's
    rows (P,): dropped rows (``rows`` False) get False."""
    full = np.zeros(len(rows), dtype=bool)
    full[rows] = mask
    return full


# What a refusal of NaN rows suggests, for a file read and for an array given in Python.
FILE_NONFINITE_HINT = (
    "pass --drop-nonfinite to drop them "
    "(in Python: read_points(..., drop_nonfinite=True), or drop the rows)"
)
ARRAY_NONFINITE_HINT = "drop those rows first (register takes drop_nonfinite=True)"


def check_cloud(
    points: object,
    name: str,
    drop_nonfinite: bool = False,
    nonfinite_hint: str = FILE_NONFINITE_HINT,
) -> tuple[np.ndarray, np.ndarray]:
    """Decide whether ``points`` is a usable cloud; return it as float64 (N, 3) and which
    of its rows were kept ((P,) bool). Extra columns (colour, intensity) are dropped.

    Args:
        points: an (N, C) array of numbers, C >= 3.
        name: what to call it in messages: a file's path, ``"template"`` or ``"source"``.
        drop_nonfinite: drop rows holding NaN or inf instead of refusing the cloud.
        nonfinite_hint: what the refusal of such rows suggests.

    Raises:
        MaskNetError: one line naming ``name`` and the problem.

    Warns:
        MaskNetWarning: 3-10 points, or one point far out (see :func:`check_geometry`).
    """
    from_cloud = from_open3d(points)  # an Open3D point cloud: its points
    array = np.asarray(points if from_cloud is None else from_cloud)
    if array.dtype.kind not in "iuf":
        raise MaskNetError(f"{name}: expected numbers, got an array of dtype {array.dtype}")
    if array.ndim == 2 and array.shape[0] == 3 and array.shape[1] > 3:
        raise MaskNetError(
            f"{name}: shape {array.shape} looks transposed (3 rows of coordinates); "
            "pass an (N, 3) array, one point per row (its .T)"
        )
    if array.ndim != 2 or array.shape[1] < 3:
        if array.size == 0:
            raise MaskNetError(f"{name}: no points")
        raise MaskNetError(
            f"{name}: expected an (N, 3) array of points (extra columns allowed), "
            f"got shape {tuple(array.shape)}"
        )
    cloud = np.ascontiguousarray(array[:, :3], dtype=np.float64)
    if len(cloud) == 0:
        raise MaskNetError(f"{name}: no points")
    finite = np.isfinite(cloud).all(axis=1)
    n_bad = int(len(cloud) - finite.sum())
    if n_bad:
        if not drop_nonfinite:
            rows = "1 row contains" if n_bad == 1 else f"{n_bad} rows contain"
            every = " (all of them)" if n_bad == len(cloud) else ""
            raise MaskNetError(f"{name}: {rows} NaN or inf{every}; {nonfinite_hint}")
        cloud = cloud[finite]
        if len(cloud) == 0:
            raise MaskNetError(f"{name}: all {n_bad} points contain NaN or inf; none remain")
    if len(cloud) < MIN_POINTS:
        raise MaskNetError(f"{name}: only {len(cloud)} point(s); at least 3 are needed")
    largest = float(np.abs(cloud).max())
    if largest > FLOAT32_MAX:
        raise MaskNetError(
            f"{name}: coordinates up to {largest:.3g}, beyond float32's range "
            f"({FLOAT32_MAX:.3g}); rescale the cloud"
        )
    if largest > LARGEST_COORDINATE:
        raise MaskNetError(
            f"{name}: coordinates up to {largest:.3g}: squared distances would overflow "
            f"float32 (coordinates must stay under {LARGEST_COORDINATE:.0e}); rescale the cloud"
        )
    check_geometry(cloud, name)
    return cloud, finite


def check_geometry(points: np.ndarray, name: str) -> None:
    """Refuse clouds (N, 3) with no 3-D extent to register, and warn
    (:class:`~masknet.errors.MaskNetWarning`) where a result will be unreliable: 3-10
    points, or one point so far out that it sets the cloud's spread (more than 1,000
    times the median distance from the median)."""
    centred = points - np.median(points, axis=0)
    deviation = centred - centred.mean(0)
    # Singular values of the centred cloud, from its 3x3 scatter (no (N, 3) copy).
    spread = np.sqrt(np.clip(np.linalg.eigvalsh(deviation.T @ deviation), 0, None))[::-1]
    if spread[0] <= 1e-12 * max(1.0, float(np.abs(points).max())):
        raise MaskNetError(f"{name}: all {len(points)} points are identical")
    if spread[1] <= 1e-6 * spread[0]:  # (square roots of eigenvalues: 1e-6, not 1e-12)
        raise MaskNetError(f"{name}: all {len(points)} points lie on one line; nothing to register")
    if len(points) <= FEW_POINTS:
        _warn(f"{name}: only {len(points)} points; the result is unreliable")
    distance = np.linalg.norm(centred, axis=1)
    typical = float(np.median(distance))
    if typical > 0 and distance.max() > 1000 * typical:
        _warn(
            f"{name}: one point lies {distance.max() / typical:.3g} times farther out "
            "than the median point; an outlier sets the cloud's scale"
        )


def _warn(message: str) -> None:
    warn(message, stacklevel=5)


_PLY_SIZES = {
    **dict.fromkeys(("char", "uchar", "int8", "uint8"), 1),
    **dict.fromkeys(("short", "ushort", "int16", "uint16"), 2),
    **dict.fromkeys(("int", "uint", "int32", "uint32", "float", "float32"), 4),
    **dict.fromkeys(("double", "float64"), 8),
}


def check_ply_body(name: str) -> None:
    """Raise if a PLY body holds more or fewer records than its header declares.

    ASCII bodies are counted by lines; binary ones by bytes (where every element has
    fixed-size properties; list properties, as in faces, make sizes vary, and then
    only the reader's own checks apply). Readers take the header's count on trust.
    """
    with open(name, "rb") as fh:
        header, elements, fmt = [], [], ""
        for _ in range(10_000):
            line = fh.readline()
            if not line:
                return  # no end_header: the reader reports the file as corrupt
            words = line.decode("latin-1").split()
            header.append(words)
            if words[:1] == ["format"] and len(words) > 1:
                fmt = words[1]
            elif words[:1] == ["element"] and len(words) == 3 and words[2].isdigit():
                elements.append([words[1], int(words[2]), 0])  # name, count, record bytes
            elif words[:1] == ["property"] and elements:
                size = (
                    None
                    if words[1:2] == ["list"]
                    else _PLY_SIZES.get(words[1] if len(words) > 1 else "")
                )
                elements[-1][2] = (
                    None if size is None or elements[-1][2] is None else elements[-1][2] + size
                )
            elif words[:1] == ["end_header"]:
                break
        else:
            return
        start = fh.tell()
        # ASCII rows counted line by line, so memory does not grow with the file.
        rows = sum(1 for row in fh if row.strip()) if fmt == "ascii" else None
    declared = {e[0]: e[1] for e in elements}
    vertices = declared.get("vertex", 0)
    if rows is not None:
        expected = sum(e[1] for e in elements)
        if rows != expected:
            raise MaskNetError(
                f"{name}: the PLY header declares {vertices} vertices"
                + (f" ({expected} records in all)" if expected != vertices else "")
                + f" but the body has {rows} rows"
            )
    elif fmt.startswith("binary") and all(e[2] is not None for e in elements):
        expected = sum(e[1] * e[2] for e in elements)
        actual = os.path.getsize(name) - start
        if actual < expected:
            raise MaskNetError(
                f"{name}: truncated or corrupt .ply file (the header declares {vertices} "
                f"vertices, {expected} bytes; the body has {actual})"
            )
        if actual > expected:
            raise MaskNetError(
                f"{name}: the PLY header declares {vertices} vertices ({expected} bytes) "
                f"but the body has data beyond them ({actual} bytes)"
            )


def check_pcd_body(name: str) -> None:
    """Raise if a PCD's header is inconsistent, or its body holds more or fewer points
    than ``POINTS`` declares (ascii rows, binary bytes, or the size recorded in a
    ``binary_compressed`` body). Open3D takes the header on trust and returns
    uninitialised memory, or fails to allocate, when it lies."""
    fields: dict[str, list[str]] = {}
    with open(name, "rb") as fh:
        for _ in range(64):
            line = fh.readline()
            if not line:
                raise MaskNetError(f"{name}: truncated or corrupt .pcd file (no DATA line)")
            words = line.decode("latin-1").split()
            if not words or words[0].startswith("#"):
                continue
            fields[words[0].upper()] = words[1:]
            if words[0].upper() == "DATA":
                break
        else:
            raise MaskNetError(f"{name}: corrupt .pcd header (no DATA line)")
        start = fh.tell()
        head = fh.read(8)
    try:
        points = int(fields["POINTS"][0])
        width, height = int(fields["WIDTH"][0]), int(fields["HEIGHT"][0])
        sizes = [int(v) for v in fields["SIZE"]]
        counts = [int(v) for v in fields.get("COUNT", ["1"] * len(sizes))]
        data = fields["DATA"][0].lower()
    except (KeyError, IndexError, ValueError):
        raise MaskNetError(
            f"{name}: corrupt .pcd header (POINTS, WIDTH, HEIGHT, SIZE or DATA)"
        ) from None
    if width * height != points or points < 0:
        raise MaskNetError(
            f"{name}: the PCD header declares {points} points but WIDTH x HEIGHT is "
            f"{width} x {height}"
        )
    record = sum(sz * c for sz, c in zip(sizes, counts, strict=False))
    body = os.path.getsize(name) - start
    if data == "ascii":
        with open(name, "rb") as fh:
            fh.seek(start)
            rows = sum(1 for row in fh if row.strip())
        if rows != points:
            raise MaskNetError(
                f"{name}: the PCD header declares {points} points but the body has {rows} rows"
            )
    elif data == "binary" and body < points * record:
        raise MaskNetError(
            f"{name}: truncated or corrupt .pcd file (the header declares {points} points, "
            f"{points * record} bytes; the body has {body})"
        )
    elif data == "binary" and body > points * record:
        raise MaskNetError(
            f"{name}: the PCD header declares {points} points ({points * record} bytes) but "
            f"the body has data beyond them ({body} bytes)"
        )
    elif data == "binary_compressed" and len(head) == 8:
        _, raw = np.frombuffer(head, dtype="<u4")
        if int(raw) != points * record:
            raise MaskNetError(
                f"{name}: the PCD header declares {points} points ({points * record} bytes) but "
                f"the compressed body holds {int(raw)} bytes"
            )

"""Open3D's normals and FPFH features in vectorised numpy, without Open3D.

The mask networks' descriptor inputs (:mod:`masknet.models.descriptors`) were trained on
Open3D's features; without Open3D, this module computes the same numbers, every point at
once (no faster than Open3D's compiled loops), from one KD-tree query per cloud
(:func:`masknet.geometry.knn.cloud_tree`). Each step follows Open3D 0.20's own
definition, named in its docstring:

* neighbours: Open3D's hybrid search (``KDTreeFlann::SearchHybrid``): the ``max_nn``
  nearest points, the point itself included, then those at squared distance strictly below
  ``radius**2``;
* normals (``PointCloud::EstimateNormals`` with ``fast_normal_computation``): the
  covariance of the neighbours from their raw moments (``utility::ComputeCovariance``), the
  identity where fewer than 3 neighbours; its smallest eigenvector by the closed-form
  symmetric 3x3 solver ``FastEigen3x3`` (geometrictools' robust eigensolver, with its
  diagonal-matrix branch), and (0, 0, 1) where that gives none (a zero covariance);
* orientation (``PointCloud::OrientNormalsTowardsCameraLocation``): each normal flipped
  where it points away from the location;
* FPFH (``pipelines/registration/Feature.cpp``): the pair features of
  ``ComputePairFeatures``, 11 bins each of the angle, v.n2 and the cosine in
  ``ComputeSPFHFeature`` (each histogram summing to 100), and ``ComputeFPFHFeature``'s
  weighting of the neighbours' histograms by inverse squared distance (each histogram then
  sums to 200).

Agreement with Open3D and the cost are in docs/RESULTS.md (CrossMaskNet's cost).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = [
    "fpfh_histograms",
    "hybrid_neighbours",
    "open3d_fpfh",
    "open3d_normals",
    "orient_towards",
    "smallest_eigenvectors",
]

# Open3D's FastEigen3x3 writes 2 pi / 3 with this literal.
_TWO_THIRDS_PI = 2.09439510239319549
# Where numpy's vectorised acos/atan2 could round to the other side of a comparison than
# the C library's (both are within a few units in the last place; this is far wider).
_NEAR = 1e-12


def hybrid_neighbours(
    points: np.ndarray, max_nn: int, tree: Any | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The ``max_nn`` nearest points of every point of ``points`` (P, 3), itself included,
    nearest first: indices (P, k) int64 and squared distances (P, k) float64, k =
    min(max_nn, P). Open3D's hybrid search keeps those with squared distance < radius**2;
    the caller cuts by its radius (one query serves several radii). ``tree``:
    :func:`masknet.geometry.knn.cloud_tree` of ``points`` (built here when None)."""
    from masknet.geometry.knn import cloud_tree

    tree = cloud_tree(points) if tree is None else tree
    k = min(max_nn, len(points))
    d2, idx = tree.query(points, k=k, sqr_dists=True)
    return idx.astype(np.int64).reshape(len(points), k), np.asarray(d2).reshape(len(points), k)


def _covariances(points: np.ndarray, idx: np.ndarray, within: np.ndarray) -> np.ndarray:
    """(P, 3, 3): the covariance of each point's neighbours ``idx`` (P, k) where ``within``
    (P, k), from raw moments summed neighbour by neighbour, nearest first, as Open3D's
    ``ComputeCovariance`` (E[xx^T] - E[x]E[x]^T; numpy sums an outer axis in order, so the
    roundings are Open3D's, and they decide the tie-breaks of :func:`_pair_bins` between
    points of one neighbourhood); the identity where fewer than 3 neighbours
    (``EstimatePerPointCovariances``)."""
    x, y, z = np.where(within.T[None], points.T[:, idx.T], 0.0)  # (k, P) each
    moments = np.stack([x, y, z, x * x, x * y, x * z, y * y, y * z, z * z], 1).sum(0)
    count = within.sum(1)
    moments /= np.maximum(count, 1)
    cov = np.empty((len(points), 3, 3))
    for m, (a, b) in enumerate(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
        cov[:, a, b] = cov[:, b, a] = moments[3 + m] - moments[a] * moments[b]
    cov[count < 3] = np.eye(3)
    return cov


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products (...,) of (..., 3) arrays, summed x, y, z in order (Eigen's)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _eigenvector_of(a: np.ndarray, value: np.ndarray) -> np.ndarray:
    """(P, 3) unit eigenvectors of the symmetric ``a`` (P, 3, 3) for the simple eigenvalues
    ``value`` (P,): the largest cross product of two rows of a - value I (Open3D's
    ``ComputeEigenvector0``; first of equal ones)."""
    rows = a - value[:, None, None] * np.eye(3)
    crosses = np.stack(
        [
            np.cross(rows[:, 0], rows[:, 1]),
            np.cross(rows[:, 0], rows[:, 2]),
            np.cross(rows[:, 1], rows[:, 2]),
        ],
        1,
    )  # (P, 3 pairs, 3)
    lengths = _dot(crosses, crosses)
    best = np.zeros(len(a), np.int64)
    best[lengths[:, 1] > lengths[:, 0]] = 1
    best[lengths[:, 2] > lengths[np.arange(len(a)), best]] = 2
    pick = np.arange(len(a))
    return crosses[pick, best] / np.sqrt(lengths[pick, best])[:, None]


def _second_eigenvector(a: np.ndarray, first: np.ndarray, value: np.ndarray) -> np.ndarray:
    """(P, 3): the eigenvector of ``a`` (P, 3, 3) for ``value`` (P,) orthogonal to the unit
    eigenvector ``first`` (P, 3), from the 2x2 problem on an orthonormal pair (U, V)
    orthogonal to ``first`` (Open3D's ``ComputeEigenvector1``)."""
    x, y, z = first[:, 0], first[:, 1], first[:, 2]
    by_x = np.abs(x) > np.abs(y)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_x, inv_y = 1 / np.sqrt(x * x + z * z), 1 / np.sqrt(y * y + z * z)
        zero = np.zeros_like(x)
        u = np.where(
            by_x[:, None],
            np.stack([-z * inv_x, zero, x * inv_x], 1),
            np.stack([zero, z * inv_y, -y * inv_y], 1),
        )
        v = np.cross(first, u)
        au, av = _dot(a, u[:, None, :]), _dot(a, v[:, None, :])
        m00 = _dot(u, au) - value
        m01 = _dot(u, av)
        m11 = _dot(v, av) - value
        # Rotate by the larger diagonal entry of the 2x2 matrix, as Open3D does.
        on_00 = np.abs(m00) >= np.abs(m11)
        diag = np.where(on_00, m00, m11)
        big_diag = np.abs(diag) >= np.abs(m01)
        t = np.where(big_diag, m01 / diag, diag / m01)
        c = 1 / np.sqrt(1 + t * t)
        diag_n = np.where(big_diag, c, t * c)
        off_n = np.where(big_diag, t * c, c)
        rotated = np.where(
            on_00[:, None],
            off_n[:, None] * u - diag_n[:, None] * v,
            diag_n[:, None] * u - off_n[:, None] * v,
        )
    flat = np.maximum(np.abs(diag), np.abs(m01)) == 0
    return np.where(flat[:, None], u, rotated)


def _libm(function: Any, values: np.ndarray) -> np.ndarray:
    """``function`` (one of :mod:`math`'s) of each of ``values`` (n,): the C library's
    rounding, which Open3D gets; numpy's vectorised ``arccos``/``cos`` may round otherwise
    (SIMD kernels), and the solver's branches and the ties of :func:`_pair_bins` follow."""
    return np.fromiter(map(function, values.tolist()), np.float64, len(values))


def smallest_eigenvectors(cov: np.ndarray) -> np.ndarray:
    """(P, 3) float64: the unit eigenvector of the smallest eigenvalue of each symmetric
    ``cov`` (P, 3, 3), exactly as Open3D's ``FastEigen3x3`` (geometrictools' robust
    closed form on the matrix scaled by its largest entry; on a diagonal matrix the axis of
    the strictly smallest entry, else z), and zeros for a zero matrix."""
    n = len(cov)
    out = np.zeros((n, 3))
    scale = cov.reshape(n, 9).max(1)
    live = scale != 0
    a = cov[live] / scale[live, None, None]
    off = a[:, 0, 1] ** 2 + a[:, 0, 2] ** 2 + a[:, 1, 2] ** 2
    full = off > 0
    # Diagonal matrices: Open3D compares the unscaled entries.
    d = cov[live][~full][:, [0, 1, 2], [0, 1, 2]]
    axis = np.full(len(d), 2)
    axis[(d[:, 1] < d[:, 0]) & (d[:, 1] < d[:, 2])] = 1
    axis[(d[:, 0] < d[:, 1]) & (d[:, 0] < d[:, 2])] = 0
    diagonal = np.zeros((len(d), 3))
    diagonal[np.arange(len(d)), axis] = 1.0
    a, off = a[full], off[full]
    q = (a[:, 0, 0] + a[:, 1, 1] + a[:, 2, 2]) / 3
    b00, b11, b22 = a[:, 0, 0] - q, a[:, 1, 1] - q, a[:, 2, 2] - q
    p = np.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + off * 2) / 6)
    c00 = b11 * b22 - a[:, 1, 2] * a[:, 1, 2]
    c01 = a[:, 0, 1] * b22 - a[:, 1, 2] * a[:, 0, 2]
    c02 = a[:, 0, 1] * a[:, 1, 2] - b11 * a[:, 0, 2]
    det = (b00 * c00 - a[:, 0, 1] * c01 + a[:, 0, 2] * c02) / (p * p * p)
    half_det = np.clip(det * 0.5, -1.0, 1.0)
    angle = _libm(math.acos, half_det) / 3.0
    beta2 = _libm(math.cos, angle) * 2
    beta0 = _libm(math.cos, angle + _TWO_THIRDS_PI) * 2
    beta1 = -(beta0 + beta2)
    e0, e1, e2 = q + p * beta0, q + p * beta1, q + p * beta2
    # From the eigenvalue farthest from the middle one (e2 when half_det >= 0, else e0).
    high = half_det >= 0
    start_value = np.where(high, e2, e0)
    first = _eigenvector_of(a, start_value)
    first_smallest = np.where(high, (e2 < e0) & (e2 < e1), (e0 < e1) & (e0 < e2))
    second = _second_eigenvector(a, first, e1)
    second_smallest = (e1 < e0) & (e1 < e2)
    third = np.where(high[:, None], np.cross(second, first), np.cross(first, second))
    chosen = np.where(
        first_smallest[:, None], first, np.where(second_smallest[:, None], second, third)
    )
    result = np.zeros((len(full), 3))
    result[full] = chosen
    result[~full] = diagonal
    out[live] = result
    return out


def open3d_normals(points: np.ndarray, idx: np.ndarray, within: np.ndarray) -> np.ndarray:
    """Unit normals (P, 3) float64 of ``points`` (P, 3) as Open3D's ``estimate_normals``
    (fast solver) from hybrid neighbours ``idx`` (P, k) cut to ``within`` (P, k) bool
    (:func:`hybrid_neighbours`): signs as the solver gives them, (0, 0, 1) where the
    covariance is zero."""
    normals = smallest_eigenvectors(_covariances(points, idx, within))
    normals[np.linalg.norm(normals, axis=1) == 0] = (0.0, 0.0, 1.0)
    return normals


def orient_towards(points: np.ndarray, normals: np.ndarray, location: np.ndarray) -> np.ndarray:
    """``normals`` (P, 3) each flipped where it points away from ``location`` (3,) seen from
    its point of ``points`` (P, 3) (Open3D's ``orient_normals_towards_camera_location``;
    a zero normal becomes the unit direction to the location, or (0, 0, 1))."""
    towards = location[None, :] - points
    out = np.where((_dot(normals, towards) < 0)[:, None], -normals, normals)
    zero = np.linalg.norm(out, axis=1) == 0
    if zero.any():
        length = np.linalg.norm(towards[zero], axis=1, keepdims=True)
        out[zero] = np.where(length > 0, towards[zero] / np.where(length > 0, length, 1), 0)
        out[zero & (np.linalg.norm(out, axis=1) == 0)] = (0.0, 0.0, 1.0)
    return out


def _atan2_binned(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """atan2(y, x), elementwise: numpy's, with the C library's near the bin edges of
    :func:`_pair_bins` (k pi / 11 - pi, shifted by the rounding of the bin formula)."""
    angle = np.arctan2(y, x)
    edge = 11 * (angle + np.pi) / (2.0 * np.pi)
    close = np.flatnonzero(np.abs(edge - np.round(edge)) <= _NEAR)
    if len(close):
        pairs = zip(y.flat[close].tolist(), x.flat[close].tolist(), strict=True)
        angle.flat[close] = np.fromiter((math.atan2(*p) for p in pairs), np.float64, len(close))
    return angle


def _cross(a: tuple, b: tuple) -> tuple:
    """The cross product a x b of vectors given as their three component arrays."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _dot3(a: tuple, b: tuple) -> np.ndarray:
    """The dot product of vectors given as their three component arrays, x, y, z in order."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _pair_bins(
    points: np.ndarray, normals: np.ndarray, first: np.ndarray, second: np.ndarray
) -> np.ndarray:
    """(3, M) int64 bins 0..10 of Open3D's ``ComputePairFeatures`` of the M pairs of points
    ``first`` (M,) and ``second`` (M,) (indices into ``points`` (P, 3) and ``normals``
    (P, 3)): the angle, v.n2 and the cosine of the source normal with the line, 11 bins
    each of [-pi, pi], [-1, 1], [-1, 1] as ``ComputeSPFHFeature``. A coincident pair, or a
    line along the source normal, has features 0 (the middle bins)."""
    pt, nt = points.T, normals.T
    p1, n1 = pt[:, first], nt[:, first]
    line = tuple(pt[:, second] - p1)
    n1, n2 = tuple(n1), tuple(nt[:, second])
    length = np.sqrt(_dot3(line, line))
    with np.errstate(divide="ignore", invalid="ignore"):
        cos1 = _dot3(n1, line) / length
        cos2 = _dot3(n2, line) / length
        # The normal at the smaller angle to the line is the source: Open3D >= 0.20 compares
        # the cosines' magnitudes (|cos1| < |cos2| swaps; 0.19 and older compared their
        # acos, which differs only in near-ties, in the last bits).
        swap = np.abs(cos1) < np.abs(cos2)
        src = tuple(np.where(swap, b, a) for a, b in zip(n1, n2, strict=True))
        dst = tuple(np.where(swap, a, b) for a, b in zip(n1, n2, strict=True))
        sign = np.where(swap, -1.0, 1.0)
        line = tuple(c * sign for c in line)
        cosine = np.where(swap, -cos2, cos1)
        v = _cross(line, src)
        v_len = np.sqrt(_dot3(v, v))
        v = tuple(c / v_len for c in v)
        w = _cross(src, v)
        alpha = _dot3(v, dst)
        theta = _atan2_binned(_dot3(w, dst), _dot3(src, dst))
    zero = (length == 0) | (v_len == 0)
    bins = np.stack(
        [
            np.floor(11 * (theta + np.pi) / (2.0 * np.pi)),
            np.floor(11 * (alpha + 1.0) * 0.5),
            np.floor(11 * (cosine + 1.0) * 0.5),
        ]
    )
    bins[:, zero] = 5  # features 0
    return np.clip(bins, 0, 10).astype(np.int64)


def fpfh_histograms(
    points: np.ndarray, normals: np.ndarray, idx: np.ndarray, d2: np.ndarray, within: np.ndarray
) -> np.ndarray:
    """FPFH (P, 33) float64 of ``points`` (P, 3) with unit ``normals`` (P, 3) over hybrid
    neighbours ``idx`` (P, k) with squared distances ``d2`` (P, k) cut to ``within`` (P, k)
    (column 0: the point itself), as Open3D's ``compute_fpfh_feature``: three 11-bin
    histograms each summing to 200 (100 from the point's SPFH, 100 from its neighbours'
    weighted by inverse squared distance); zeros for a point with no neighbour."""
    from scipy.sparse import csr_matrix

    n = len(points)
    others = within.copy()
    others[:, 0] = False  # column 0 is the point (or a copy of it: both give features 0)
    count = others.sum(1)
    first, col = np.nonzero(others)  # row-major: each point's neighbours, nearest first
    second = idx[first, col]
    increment = 100.0 / np.maximum(count, 1)
    bins = _pair_bins(points, normals, first, second) + np.array([[0], [11], [22]])
    flat = (first * 33 + bins).ravel()
    spfh = np.bincount(flat, np.tile(increment[first], 3), n * 33).reshape(n, 33)
    # Each neighbour's SPFH weighted by 1 / squared distance; coincident ones skipped.
    dist = d2[first, col]
    use = dist > 0
    indptr = np.concatenate([[0], np.cumsum(np.bincount(first[use], minlength=n))])
    weights = csr_matrix((1.0 / dist[use], second[use], indptr), shape=(n, n))
    spread = (weights @ spfh).reshape(n, 3, 11)
    sums = spread.sum(-1)
    factor = np.where(sums != 0, 100.0 / np.where(sums != 0, sums, 1.0), 0.0)
    fpfh = (spread * factor[..., None]).reshape(n, 33) + spfh
    fpfh[count == 0] = 0.0
    return fpfh


def open3d_fpfh(
    points: np.ndarray,
    normal_radius: float,
    feature_radius: float,
    normal_nn: int = 30,
    feature_nn: int = 30,
    neighbours: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """FPFH (P, 33) float64 of ``points`` (P, 3), radii in the points' units, as Open3D
    gives from a cloud without normals: ``estimate_normals`` (hybrid ``normal_radius``, at
    most ``normal_nn``), ``orient_normals_towards_camera_location`` (the cloud's centroid),
    then ``compute_fpfh_feature`` (hybrid ``feature_radius``, at most ``feature_nn``).
    ``neighbours``: :func:`hybrid_neighbours` of ``points`` with at least the larger of the
    two counts where the caller has them (one query serves both searches)."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    if not len(points):
        return np.zeros((0, 33))
    if neighbours is None:
        neighbours = hybrid_neighbours(points, max(normal_nn, feature_nn))
    idx, d2 = neighbours
    near, near_d2 = idx[:, :normal_nn], d2[:, :normal_nn]
    # Open3D's cut: squared distance < radius * radius (the same rounding as its product).
    normals = open3d_normals(points, near, near_d2 < normal_radius * normal_radius)
    normals = orient_towards(points, normals, points.mean(0))
    idx, d2 = idx[:, :feature_nn], d2[:, :feature_nn]
    return fpfh_histograms(points, normals, idx, d2, d2 < feature_radius * feature_radius)

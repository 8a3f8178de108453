# Copyright 2026 The mlsemreg_ros Authors
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""
FPFH descriptors at keypoints, vectorized over point pairs (NumPy/SciPy).

FPFH (Rusu et al., "Fast Point Feature Histograms (FPFH) for 3D Registration",
ICRA 2009) of a point ``q`` with feature neighbours ``N(q)`` (radius ``r_f``)::

    SPFH(p) = 3 x 11-bin histograms of the pair features (alpha, phi, theta)
              of p with each neighbour, each histogram summing to 100
    FPFH(q) = SPFH(q) + sum_k w_k SPFH(p_k) / sum_k w_k   per 11-bin block,
              w_k = 1 / |q - p_k|^2                      (Open3D's and PCL's weighting)

Everything is computed from one list of unordered point pairs within ``r_f``
(``cKDTree.query_pairs``): the pair feature is symmetric (the "source" of a pair
is the point whose normal is more parallel to the connecting line), so every
pair is evaluated once and counted in the SPFH of both of its points.
Normals come from the same pairs (the covariance of the neighbours within
``r_n <= r_f``) and are oriented towards the sensor origin, so a surface seen
in two scans gets the same normal sign in both (Open3D leaves the sign to its
eigen solver).

``support_voxel`` > 0 computes the neighbours' SPFH on the centroids of a coarser
voxel grid of the scan (the "support"); each keypoint keeps its own position,
normal and SPFH, taken against the support, or with ``snap`` takes the FPFH of its
nearest support centroid. Pairs, and therefore the cost, drop roughly with the
square of the voxel ratio (KITTI scan 000003: 746k pairs on the 0.3 m scan grid,
128k on a 0.5 m support).
Neighbourhoods are pure radius neighbourhoods (no ``max_nn`` cap), as in PCL.

With numba (:mod:`mlsemreg_ros.core.features.kernels`) the passes over the pairs run as
compiled loops (:mod:`mlsemreg_ros.core.features.fpfh_kernels`) that give the same
descriptors bit for bit; ``compiled=False`` runs the NumPy passes below.
The one KD-tree of the support serves the normals, the features and the snapping.
"""

from __future__ import annotations

from mlsemreg_ros.core.features import fpfh_kernels, kernels
from mlsemreg_ros.core.features.features import voxel_centroids
import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

BINS = 11
"""Bins per pair feature; three features give the 33-d descriptor."""


def fpfh_at_keypoints(
    points: np.ndarray,
    indices: np.ndarray,
    normal_radius: float,
    feature_radius: float,
    support_voxel: float = 0.0,
    viewpoint: np.ndarray | None = None,
    snap: bool = False,
    compiled: bool | None = None,
) -> np.ndarray:
    """
    FPFH descriptors of the scan points ``points[indices]``.

    - ``points``: (N, 3) float64 scan in the sensor frame, metres.
    - ``indices``: (M,) int rows of ``points`` (any order, repeats allowed).
    - ``normal_radius``: radius ``r_n`` of the normal estimation neighbourhood, metres.
    - ``feature_radius``: radius ``r_f`` of the SPFH/FPFH neighbourhood, metres.
    - ``support_voxel``: > 0 computes the neighbours' histograms on the centroids of a
      voxel grid of this edge (metres); each keypoint keeps its own position, normal and
      SPFH, taken against those centroids. 0 uses the scan points themselves.
    - ``viewpoint``: (3,) point the normals face (default: the sensor origin).
    - ``snap``: with ``support_voxel`` > 0, give each keypoint the FPFH of its nearest
      support centroid instead (no neighbourhood search per keypoint: the cost no
      longer grows with the number of keypoints).
    - ``compiled``: None uses the numba kernels when available, False the NumPy passes
      (the same result).

    Returns (M, 33) float32 (blocks alpha | phi | theta); rows of points without any
    neighbour within ``feature_radius`` are all zero.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    indices = np.asarray(indices, dtype=np.int64).reshape(-1)
    if indices.shape[0] == 0 or points.shape[0] == 0:
        return np.zeros((indices.shape[0], 3 * BINS), dtype=np.float32)
    if indices.min() < 0 or indices.max() >= points.shape[0]:
        raise IndexError(f'keypoint indices must lie in [0, {points.shape[0] - 1}]')
    origin = np.zeros(3) if viewpoint is None else np.asarray(viewpoint, dtype=np.float64)
    # Work relative to the viewpoint: orientation needs no offset, float32 keeps precision.
    points = points - origin
    compiled = kernels.use_compiled(compiled)
    support = (
        voxel_centroids(points, support_voxel, compiled=compiled)[0]
        if support_voxel > 0
        else points
    )
    tree = cKDTree(support, balanced_tree=False, compact_nodes=False)  # cheaper to build
    # Keypoints that are support points reuse the support's rows and pairs.
    on_support = support_voxel <= 0 or snap
    rows = _snap(tree, points[indices], support_voxel) if support_voxel > 0 and snap else indices
    unique, row_of_keypoint = np.unique(rows, return_inverse=True)
    radius = max(feature_radius, normal_radius)
    # 1. Normals and SPFH of the support, from its unordered pairs (each serves both ends).
    pairs = tree.query_pairs(radius, output_type='ndarray')
    first, second = np.ascontiguousarray(pairs[:, 0]), np.ascontiguousarray(pairs[:, 1])
    keypoints = None if on_support else points[unique]
    describe = _describe_compiled if compiled else _describe
    fpfh = describe(support, tree, first, second, unique, keypoints, normal_radius, feature_radius)
    return fpfh[row_of_keypoint.reshape(-1)]


def _snap(tree: cKDTree, queries: np.ndarray, support_voxel: float) -> np.ndarray:
    """
    Row of the nearest support centroid of each query (a scan point).

    A point's own voxel centroid lies within the voxel diagonal ``sqrt(3) * support_voxel``,
    so the search is bounded there (a third cheaper, the same rows).
    """
    rows = tree.query(queries, distance_upper_bound=1.000001 * np.sqrt(3.0) * support_voxel)[1]
    lost = np.flatnonzero(rows >= tree.n)
    if lost.size:  # not expected: search without the bound
        rows[lost] = tree.query(queries[lost])[1]
    return rows


def _describe(
    support: np.ndarray,
    tree: cKDTree,
    first: np.ndarray,
    second: np.ndarray,
    rows: np.ndarray,
    keypoints: np.ndarray | None,
    normal_radius: float,
    feature_radius: float,
) -> np.ndarray:
    """
    FPFH (NumPy passes) of the support ``rows``, or of ``keypoints`` off the support.

    ``first, second``: the support's pairs within ``max(r_n, r_f)``. Returns (M, 33) float32.
    """
    normals, spfh, first, second, dist2 = _support_terms(
        support, first, second, normal_radius, feature_radius
    )
    if keypoints is None:
        summed = np.asarray(_pair_weights(first, second, dist2, rows, support.shape[0]) @ spfh)
        return combine(spfh[rows], summed)
    own_spfh, summed = _keypoint_terms(
        keypoints, support, tree, normals, spfh, normal_radius, feature_radius
    )
    return combine(own_spfh, summed)


def _describe_compiled(
    support: np.ndarray,
    tree: cKDTree,
    first: np.ndarray,
    second: np.ndarray,
    rows: np.ndarray,
    keypoints: np.ndarray | None,
    normal_radius: float,
    feature_radius: float,
) -> np.ndarray:
    """:func:`_describe` with the compiled passes of :mod:`fpfh_kernels` (bit-identical)."""
    first, second = first.astype(np.int64, copy=False), second.astype(np.int64, copy=False)
    coords = np.ascontiguousarray(support.T, dtype=np.float32)
    delta, dist2 = fpfh_kernels.pair_offsets(coords, first, second)
    near = np.flatnonzero(dist2 <= normal_radius**2)
    covariance = fpfh_kernels.covariances(support.shape[0], first, second, delta, near)
    normals = _compiled_normals(covariance, support)
    if normal_radius > feature_radius:  # the pairs were searched with the normal radius
        within = np.flatnonzero(dist2 <= feature_radius**2)
        first, second, delta, dist2 = (
            first.take(within),
            second.take(within),
            np.ascontiguousarray(delta.take(within, axis=1)),
            dist2.take(within),
        )
    counts, scale = _compiled_histograms(
        support.shape[0], delta, normals, first, normals, second, pairs=True
    )
    if keypoints is None:
        rows = rows.astype(np.int64, copy=False)
        summed = fpfh_kernels.support_neighbour_sums(
            rows, support.shape[0], first, second, dist2, counts, scale
        )
        return combine(fpfh_kernels.spfh_rows(counts, scale, rows), summed)
    keypoints = np.ascontiguousarray(keypoints, dtype=np.float64)
    m = keypoints.shape[0]
    owner, other, dist = _keypoint_neighbours(keypoints, tree, normal_radius, feature_radius)
    offset = fpfh_kernels.keypoint_offsets(keypoints, support, owner, other)
    near = np.flatnonzero(dist <= normal_radius)
    covariance = fpfh_kernels.covariances(m, owner, np.zeros(0, dtype=np.int64), offset, near)
    own_normals = _compiled_normals(covariance, keypoints)
    within = np.flatnonzero(dist <= feature_radius)
    owner, other, dist, offset = (
        owner.take(within),
        other.take(within),
        dist.take(within),
        np.ascontiguousarray(offset.take(within, axis=1)),
    )
    own_counts, own_scale = _compiled_histograms(
        m, offset, own_normals, owner, normals, other, pairs=False
    )
    own_spfh = fpfh_kernels.spfh_rows(own_counts, own_scale, np.arange(m))
    summed = fpfh_kernels.keypoint_neighbour_sums(m, owner, other, dist, counts, scale)
    return combine(own_spfh, summed)


def _support_terms(
    support: np.ndarray,
    first: np.ndarray,
    second: np.ndarray,
    normal_radius: float,
    feature_radius: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """
    Compute normals and SPFH of the support from its pairs within ``max(r_n, r_f)`` (NumPy).

    Returns ``(normals (3, S) float32, spfh (S, 33), first, second, dist2)``, the last
    three restricted to the pairs within ``r_f`` (``dist2`` float32).
    """
    coords = support.T.astype(np.float32)  # (3, S): one contiguous row per axis
    delta = np.stack([row.take(second) - row.take(first) for row in coords])
    dist2 = np.einsum('ij,ij->j', delta, delta)
    near = np.flatnonzero(dist2 <= normal_radius**2)
    normals = estimate_normals(
        support, (first.take(near), second.take(near)), delta.take(near, axis=1)
    )
    if normal_radius > feature_radius:  # the pairs were searched with the normal radius
        within = np.flatnonzero(dist2 <= feature_radius**2)
        first, second, delta, dist2 = (
            first.take(within),
            second.take(within),
            delta.take(within, axis=1),
            dist2.take(within),
        )
    bins = pair_feature_bins(delta, normals.take(first, axis=1), normals.take(second, axis=1))
    spfh = simplified_histograms((first, second), bins, support.shape[0])
    return normals, spfh, first, second, dist2


def _compiled_normals(covariance: np.ndarray, points: np.ndarray) -> np.ndarray:
    """:func:`orient_normals` with compiled loops; NumPy's power, ``arccos`` and ``cos``."""
    q, p, numerator = fpfh_kernels.eigen_setup(covariance)
    det = numerator / np.where(p > 0, p, 1.0) ** 3
    phi = np.arccos(np.clip(det / 2.0, -1.0, 1.0)) / 3.0
    cosine = np.cos(phi + 2.0 * np.pi / 3.0)
    return fpfh_kernels.eigen_vectors(
        covariance, q, p, cosine, np.ascontiguousarray(points, dtype=np.float64)
    )


def _compiled_histograms(
    n: int,
    delta: np.ndarray,
    normals_a: np.ndarray,
    index_a: np.ndarray,
    normals_b: np.ndarray,
    index_b: np.ndarray,
    pairs: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """SPFH ``(counts, scale)`` of ``n`` points from compiled pair features (NumPy arctan2)."""
    y, x, bins, regular = fpfh_kernels.pair_angles(delta, normals_a, index_a, normals_b, index_b)
    alpha = np.arctan2(y, x)
    second = index_b if pairs else np.zeros(0, dtype=np.int64)
    return fpfh_kernels.histograms(n, index_a, second, bins, regular, alpha)


def combine(own_spfh: np.ndarray, summed: np.ndarray) -> np.ndarray:
    """
    FPFH = own SPFH + per-block normalized, ``1/d^2``-weighted sum of neighbour SPFHs.

    - ``own_spfh``: (M, 33) SPFH of the query points.
    - ``summed``: (M, 33) ``sum_k spfh(p_k) / |q - p_k|^2`` over each query's support
      neighbours (``weights @ spfh``).

    Returns (M, 33) float32; each 11-bin block of the neighbour term sums to 100 (or 0).
    """
    summed = np.array(summed, dtype=np.float64)
    blocks = summed.reshape(-1, 3, BINS)
    totals = blocks.sum(axis=2, keepdims=True)
    blocks *= np.divide(100.0, totals, out=np.zeros_like(totals), where=totals > 0)
    return (own_spfh + summed).astype(np.float32)


def _pair_weights(
    first: np.ndarray, second: np.ndarray, dist2: np.ndarray, rows: np.ndarray, n: int
) -> sparse.csr_matrix:
    """(len(rows), n) ``1/d^2`` of the support pairs that touch the requested rows."""
    position = np.full(n, -1, dtype=np.int64)
    position[rows] = np.arange(rows.shape[0])
    at_first, at_second = position.take(first), position.take(second)
    from_first, from_second = np.flatnonzero(at_first >= 0), np.flatnonzero(at_second >= 0)
    target = np.concatenate([at_first.take(from_first), at_second.take(from_second)])
    neighbour = np.concatenate([second.take(from_first), first.take(from_second)])
    d2 = np.concatenate([dist2.take(from_first), dist2.take(from_second)])
    return sparse.csr_matrix((1.0 / d2, (target, neighbour)), shape=(rows.shape[0], n))


def _keypoint_neighbours(
    keypoints: np.ndarray, tree: cKDTree, normal_radius: float, feature_radius: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Support neighbours of each keypoint: ``(owner, other, dist)`` (a coincident one dropped)."""
    found = cKDTree(keypoints).sparse_distance_matrix(
        tree, max(feature_radius, normal_radius), output_type='ndarray'
    )
    found = found[found['v'] > 0]  # a coincident centroid is the keypoint itself
    return found['i'].astype(np.int64), found['j'].astype(np.int64), found['v']


def _keypoint_terms(
    keypoints: np.ndarray,
    support: np.ndarray,
    tree: cKDTree,
    support_normals: np.ndarray,
    spfh: np.ndarray,
    normal_radius: float,
    feature_radius: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Own SPFH and weighted neighbour SPFH sum of keypoints that are not support points."""
    m = keypoints.shape[0]
    owner, other, dist = _keypoint_neighbours(keypoints, tree, normal_radius, feature_radius)
    offset = np.ascontiguousarray((support[other] - keypoints[owner]).T, dtype=np.float32)
    near = np.flatnonzero(dist <= normal_radius)
    normals = estimate_normals(keypoints, (owner.take(near),), offset.take(near, axis=1))
    within = np.flatnonzero(dist <= feature_radius)
    owner, other, dist, offset = (
        owner.take(within),
        other.take(within),
        dist.take(within),
        offset.take(within, axis=1),
    )
    bins = pair_feature_bins(
        offset, normals.take(owner, axis=1), support_normals.take(other, axis=1)
    )
    own = simplified_histograms((owner,), bins, m)
    weights = sparse.csr_matrix((1.0 / (dist * dist), (owner, other)), shape=(m, support.shape[0]))
    return own, np.asarray(weights @ spfh)


def estimate_normals(
    points: np.ndarray, owners: tuple[np.ndarray, ...], offset: np.ndarray
) -> np.ndarray:
    """
    Estimate unit normals by PCA of each point's neighbourhood, facing the origin.

    The normal of ``p`` is the eigenvector of the smallest eigenvalue of the
    covariance of ``p`` and its neighbours; it is accumulated from the offsets
    ``d = p_neighbour - p`` (``p`` itself contributes ``d = 0``), which keeps it exact
    without subtracting large coordinates.

    - ``points``: (N, 3) float64, relative to the viewpoint.
    - ``owners``: ``(first,)`` with the (E,) row each offset belongs to, or
      ``(first, second)`` for unordered pairs: ``offset`` leads from ``first`` to
      ``second``, and counts with the opposite sign for ``second``.
    - ``offset``: (3, E) float offsets, one row per axis.

    Returns (3, N) float32 (one row per axis); points with fewer than two neighbours
    get ``+z`` flipped towards the origin.
    """
    n = points.shape[0]
    count = sum(np.bincount(owner, minlength=n) for owner in owners) + 1.0
    mean = np.empty((n, 3))
    for axis in range(3):
        total = np.bincount(owners[0], weights=offset[axis], minlength=n)
        for owner in owners[1:]:
            total -= np.bincount(owner, weights=offset[axis], minlength=n)
        mean[:, axis] = total / count
    covariance = np.empty((n, 6))
    for slot, (a, b) in enumerate(_UPPER):
        product = offset[a] * offset[b]  # the same for both signs of the offset
        total = sum(np.bincount(owner, weights=product, minlength=n) for owner in owners)
        covariance[:, slot] = total / count - mean[:, a] * mean[:, b]
    return orient_normals(covariance, points)


def orient_normals(covariance: np.ndarray, points: np.ndarray) -> np.ndarray:
    """
    Return unit normals of (N, 6) covariances (:func:`smallest_eigenvectors`) facing the origin.

    Returns (3, N) float32, one row per axis.
    """
    normals = smallest_eigenvectors(covariance)
    flip = np.einsum('ij,ij->i', normals, points) > 0  # facing away from the origin
    normals[flip] *= -1.0
    return np.ascontiguousarray(normals.T, dtype=np.float32)


_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def smallest_eigenvectors(covariance: np.ndarray) -> np.ndarray:
    """
    Return the unit eigenvector of the smallest eigenvalue of symmetric 3x3 matrices.

    Closed-form eigenvalue (trigonometric solution of the characteristic cubic),
    then the eigenvector as the largest cross product of two rows of ``A - lambda I``.

    - ``covariance``: (N, 6) upper triangles ``[a00, a01, a02, a11, a12, a22]``.

    Returns (N, 3) float64; isotropic or rank-deficient inputs fall back to a unit
    vector of the null space when one exists, else ``+z``.
    """
    a00, a01, a02, a11, a12, a22 = (np.ascontiguousarray(covariance[:, k]) for k in range(6))
    q = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    off = a01 * a01 + a02 * a02 + a12 * a12
    p = np.sqrt(np.maximum((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * off) / 6.0, 0.0))
    safe_p = np.where(p > 0, p, 1.0)
    det = (
        b00 * (b11 * b22 - a12 * a12)
        - a01 * (a01 * b22 - a12 * a02)
        + a02 * (a01 * a12 - b11 * a02)
    ) / safe_p**3
    phi = np.arccos(np.clip(det / 2.0, -1.0, 1.0)) / 3.0
    smallest = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    d00, d11, d22 = a00 - smallest, a11 - smallest, a22 - smallest
    # cross products of the rows (d00 a01 a02), (a01 d11 a12), (a02 a12 d22) of A - lambda I
    crosses = (
        (a01 * a12 - a02 * d11, a02 * a01 - d00 * a12, d00 * d11 - a01 * a01),  # r0 x r1
        (a01 * d22 - a02 * a12, a02 * a02 - d00 * d22, d00 * a12 - a01 * a02),  # r0 x r2
        (d11 * d22 - a12 * a12, a12 * a02 - a01 * d22, a01 * a12 - d11 * a02),  # r1 x r2
    )
    lengths = [x * x + y * y + z * z for x, y, z in crosses]
    best = np.where(lengths[1] > lengths[0], 1, 0)
    best = np.where(lengths[2] > np.maximum(lengths[0], lengths[1]), 2, best)
    vector = np.stack([np.choose(best, [c[axis] for c in crosses]) for axis in range(3)], axis=1)
    length = np.sqrt(np.choose(best, lengths))
    scale = np.maximum(np.abs(covariance).max(axis=1), 1e-300)
    fallback = length <= 1e-12 * scale * scale
    vector[fallback] = (0.0, 0.0, 1.0)
    length[fallback] = 1.0
    return vector / length[:, None]


def pair_feature_bins(
    delta: np.ndarray, normal_first: np.ndarray, normal_second: np.ndarray
) -> np.ndarray:
    """
    Histogram bins of the symmetric point-pair features (Rusu et al. 2009, eq. 1-2).

    With ``u`` the unit pair direction, the source is the point whose normal makes the
    smaller angle with the connecting line (``|n_s.u| >= |n_t.u|``), the Darboux frame
    is ``(n_s, v = u x n_s / |.|, w = n_s x v)`` and the features are::

        theta = u_s . n_s            (u_s points from the source to the target)
        phi   = v . n_t = (u x n_s . n_t) / sqrt(1 - theta^2)
        alpha = atan2(w . n_t, n_s . n_t)

    Expanding ``w = (u_s - theta n_s) / sqrt(1 - theta^2)`` removes every cross
    product but the triple product ``u . (n_1 x n_2)``, which is the same for both
    orderings of the pair. Pairs with ``u`` parallel to the source normal get the
    all-zero feature, as in Open3D.

    - ``delta``: (3, P) float32 ``p_2 - p_1`` (non-zero), one row per axis.
    - ``normal_first``, ``normal_second``: (3, P) float32 unit normals of ``p_1``, ``p_2``.

    Returns (3, P) int64 bins in [0, 11) for (alpha, phi, theta).
    """
    dx, dy, dz = delta
    n1x, n1y, n1z = normal_first
    n2x, n2y, n2z = normal_second
    inv_length = 1.0 / np.sqrt(dx * dx + dy * dy + dz * dz)
    along_first = (n1x * dx + n1y * dy + n1z * dz) * inv_length
    along_second = (n2x * dx + n2y * dy + n2z * dz) * inv_length
    cos_normals = n1x * n2x + n1y * n2y + n1z * n2z
    triple = (
        dx * (n1y * n2z - n1z * n2y) + dy * (n1z * n2x - n1x * n2z) + dz * (n1x * n2y - n1y * n2x)
    ) * inv_length
    swap = np.abs(along_first) < np.abs(along_second)
    theta = np.where(swap, -along_second, along_first)
    along_target = np.where(swap, -along_first, along_second)
    sine = np.sqrt(np.maximum(1.0 - theta * theta, 0.0))
    regular = sine > 1e-6
    sine = np.where(regular, sine, 1.0)
    phi = np.where(regular, triple / sine, 0.0)
    alpha = np.where(
        regular, np.arctan2(along_target - theta * cos_normals, cos_normals * sine), 0.0
    )
    theta = np.where(regular, theta, 0.0)
    return np.stack([_bin(alpha, -np.pi, np.pi), _bin(phi, -1.0, 1.0), _bin(theta, -1.0, 1.0)])


def _bin(values: np.ndarray, low: float, high: float) -> np.ndarray:
    scaled = np.floor((values - low) * (BINS / (high - low)))
    return np.clip(scaled, 0, BINS - 1).astype(np.int64)


def simplified_histograms(owners: tuple[np.ndarray, ...], bins: np.ndarray, n: int) -> np.ndarray:
    """
    SPFH: three 11-bin histograms of each point's pair features, each summing to 100.

    - ``owners``: tuple of (E,) int rows; every pair feature counts for the point of
      each of them (``(first, second)`` for symmetric pairs).
    - ``bins``: (3, E) int bins of (alpha, phi, theta) from :func:`pair_feature_bins`.
    - ``n``: number of points N.

    Returns (N, 33) float64; points without pairs have all-zero rows.
    """
    size = bins.shape[1]
    codes = np.empty((len(owners), 3, size), dtype=np.int64)
    for at, owner in enumerate(owners):
        base = owner * (3 * BINS)
        for k in range(3):
            np.add(base, bins[k], out=codes[at, k])
            codes[at, k] += k * BINS
    histogram = np.bincount(codes.reshape(-1), minlength=n * 3 * BINS).reshape(n, 3 * BINS)
    degree = sum(np.bincount(owner, minlength=n) for owner in owners)
    return histogram * (100.0 / np.maximum(degree, 1))[:, None]

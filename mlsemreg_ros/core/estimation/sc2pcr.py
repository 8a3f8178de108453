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
SC2-PCR: second-order spatial compatibility for robust point cloud registration.

Implements the estimator of Chen et al., "SC2-PCR: A Second Order Spatial
Compatibility for Efficient and Robust Point Cloud Registration", CVPR 2022,
following the stages of the authors' reference code, in NumPy/SciPy for a CPU:

1. length consistency ``c_ij = | ||p_i - p_j|| - ||q_i - q_j|| |`` and the
   first-order compatibility ``SC_ij = max(0, 1 - c_ij^2 / d^2)`` (paper eq. 2),
   kept as a sparse matrix (its support is ``hard_ij = c_ij < d``);
2. the leading eigenvector of ``SC`` by power iteration; seeds are its local
   maxima (non-maximum suppression within ``nms_radius`` in the source cloud),
   at most ``seed_ratio * K`` of them, best first;
3. the second-order compatibility of the seed rows,
   ``SC2 = hard ⊙ (tight @ tight)`` with ``tight_ij = c_ij < d / 2`` (eq. 4);
4. per seed, the ``k1`` correspondences most SC2-compatible with it, then
   among those the ``k2`` best by their local second-order score, a weighted
   SVD whose weights are the leading eigenvector of the local ``SC`` (Sec. 3.4);
5. the hypothesis with most inliers (residual < ``inlier_threshold``) wins and
   is refined by reweighted least squares on its inliers.  All hypotheses are
   returned too, most inliers first (:class:`Hypotheses`):
   :func:`~mlsemreg_ros.core.poses.distinct_hypotheses` picks the best distinct ones for hypothesis
   verification on the dense scans (``core/estimation/verification.py``, beyond the paper).

Departures from the reference code, all deliberate:

- where it pads a seed's consensus set with arbitrary correspondences of zero
  compatibility (fewer than ``k1`` exist), they are masked out here; ties are
  broken by correspondence index, so results are deterministic;
- every threshold comes from :class:`EstimatorConfig` (the reference hard-codes
  the refinement threshold, 1.2 m unless the inlier threshold is 0.10);
- non-finite correspondences are ignored (never inliers);
- a CPU work budget may keep fewer seeds than ``seed_ratio * K`` when the
  compatibility is dense (``core/estimation/second_order.py``).

Performance (K ~ 6000 on 2 cores): ``K x K`` matrices are never dense.  The
length consistency is computed for the upper triangle in row blocks (float32
when the coordinate extent allows, see :func:`compatibility_matrix`) and only
entries with ``c < d`` are kept, as a symmetric CSR matrix (a few percent of the
entries for plain matches, 5-20 % for ML-SemReg matches).  The SC2 rows of the
seeds are counted without a sparse matrix product: correspondences compatible
with many seeds as packed bit sets, the rest by enumeration
(:func:`~mlsemreg_ros.core.estimation.second_order.second_order_compatibility`).  Matrix products
are
kept small enough for OpenBLAS to run them single-threaded.
"""

from __future__ import annotations

from collections.abc import Callable
import dataclasses
import time

from mlsemreg_ros.core.estimation import kernels
from mlsemreg_ros.core.estimation.config import EstimatorConfig
from mlsemreg_ros.core.estimation.second_order import (
    budget_seeds,
    seed_consensus_sets,
    tight_compatibility,
)
from mlsemreg_ros.core.features.kernels import use_compiled
from mlsemreg_ros.core.poses import residuals
from mlsemreg_ros.core.results import EstimateResult, Hypotheses
from mlsemreg_ros.core.rigid import weighted_rigid_transform
import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

#: Largest m * n * k of one matrix product.  OpenBLAS runs products below about
#: 2 * 262144 on one thread; its threaded products are up to 10x slower when the
#: cores are busy (measured), so every product here stays below this.
_BLAS_MAX_MNK = 500_000


def sc2pcr(src: np.ndarray, dst: np.ndarray, config: EstimatorConfig) -> EstimateResult:
    """
    Estimate ``T_dst_src`` from putative correspondences with SC2-PCR.

    - ``src``: ``(K, 3)`` source points of the correspondences, metres.
    - ``dst``: ``(K, 3)`` target points, row ``i`` matched to ``src[i]``.
    - ``config``: thresholds and sizes (``compatibility_threshold`` is SC2-PCR's
      ``d_thr``; ``inlier_threshold`` selects the hypothesis;
      ``refine_threshold`` is used by the post-refinement). With more than
      ``config.graph_size`` correspondences the graph (compatibility, seeds, consensus
      sets, hypotheses) is built on a seeded random subset of that size, like the
      ``max_points`` sampling of the SC2-PCR reference code; every hypothesis is still
      scored, and the winner refined, on all ``K``.

    Returns the transform, ``inlier_mask = residual < inlier_threshold`` under it, every
    seed's hypothesis (unrefined, most inliers first; the first is the refined winner's
    start) and diagnostics: ``n_seeds`` (``n_seeds_nms`` before the work budget),
    ``best_hypothesis_inliers``, ``refine_iterations``,
    ``leading_eigenvalue`` (Rayleigh quotient of the first-order compatibility matrix, the
    spectral confidence of SC2-PCR), ``sc_density`` and per-stage times ``sc2_*_ms``.
    """
    start = time.perf_counter()
    timings: dict[str, float] = {}
    src = np.asarray(src, dtype=np.float64).reshape(-1, 3)
    dst = np.asarray(dst, dtype=np.float64).reshape(-1, 3)
    if src.shape != dst.shape:
        raise ValueError(f'src and dst must have the same shape, got {src.shape}, {dst.shape}')
    total = src.shape[0]
    finite = np.isfinite(src).all(axis=1) & np.isfinite(dst).all(axis=1)
    rows = np.flatnonzero(finite)
    p_all, q_all = src[rows], dst[rows]
    graph = graph_rows(rows.size, config.graph_size)
    p, q = p_all[graph], q_all[graph]
    count = graph.size
    diagnostics: dict = {
        'n_correspondences': total,
        'n_seeds': 0,
        'best_hypothesis_inliers': 0,
        'refine_iterations': 0,
        'leading_eigenvalue': 0.0,
        'graph_correspondences': int(count),
    }
    if count < 3:
        diagnostics['message'] = f'sc2pcr needs at least 3 finite correspondences, got {count}'
        return EstimateResult(np.eye(4), np.zeros(total, dtype=bool), diagnostics)

    d = config.compatibility_threshold
    # 1. first-order compatibility (eq. 2), sparse
    tick = time.perf_counter()
    sc = compatibility_matrix(p, q, d)
    timings['sc2_compatibility_ms'] = _ms(tick)
    diagnostics['sc_density'] = sc.nnz / float(count * count)

    # 2. leading eigenvector, seeds by non-maximum suppression
    tick = time.perf_counter()
    scores, eigenvalue = leading_eigenvector(sc, config.power_iterations)
    max_seeds = max(1, int(count * config.seed_ratio))
    seeds = pick_seeds(p, scores, config.nms_radius, max_seeds)
    tight = tight_compatibility(sc)
    diagnostics['n_seeds_nms'] = int(seeds.size)
    budget_ms = config.second_order_budget
    seeds = budget_seeds(sc, tight, seeds, budget_ms * 1e6 if budget_ms > 0 else np.inf)
    timings['sc2_seeds_ms'] = _ms(tick)
    diagnostics['leading_eigenvalue'] = eigenvalue
    diagnostics['n_seeds'] = int(seeds.size)

    # 3. second-order compatibility of the seed rows (eq. 4)
    tick = time.perf_counter()
    k1 = min(config.k1, count)
    k2 = min(config.k2, k1)
    consensus, valid = seed_consensus_sets(sc, seeds, k1, tight)
    timings['sc2_second_order_ms'] = _ms(tick)

    # 4. one hypothesis per seed: two-stage sampling + weighted SVD
    tick = time.perf_counter()
    hypotheses = seed_hypotheses(p, q, consensus, valid, k2, d, config.power_iterations)
    timings['sc2_hypotheses_ms'] = _ms(tick)

    # 5. most inliers wins, then reweighted least squares
    tick = time.perf_counter()
    inlier_counts = count_inliers(hypotheses, p_all, q_all, config.inlier_threshold)
    best = int(np.argmax(inlier_counts))
    ranking = np.argsort(-inlier_counts, kind='stable')  # ranking[0] == best
    candidates = Hypotheses(hypotheses[ranking], inlier_counts[ranking])
    diagnostics['best_hypothesis_inliers'] = int(inlier_counts[best])
    timings['sc2_selection_ms'] = _ms(tick)
    if count < rows.size and inlier_counts[best] < config.graph_retry_inliers:
        # Too few inliers in the sample to seed the true pose (inlier ratio ~1 %):
        # run again on every correspondence.
        retry = sc2pcr(src, dst, dataclasses.replace(config, graph_size=0))
        retry.diagnostics.update(
            {
                'graph_retried': True,
                'sampled_best_inliers': int(inlier_counts[best]),
                'sc2_total_ms': _ms(start),
            }
        )
        return retry
    tick = time.perf_counter()
    transform, iterations = post_refinement(
        hypotheses[best], p_all, q_all, config.refine_threshold, config.refine_iterations
    )
    diagnostics['refine_iterations'] = iterations
    timings['sc2_refine_ms'] = _ms(tick)

    inlier_mask = np.zeros(total, dtype=bool)
    inlier_mask[rows] = residuals(transform, p_all, q_all) < config.inlier_threshold
    timings['sc2_total_ms'] = _ms(start)
    diagnostics.update(timings)
    return EstimateResult(transform, inlier_mask, diagnostics, candidates)


def graph_rows(count: int, graph_size: int) -> np.ndarray:
    """
    Rows of the correspondences that form the compatibility graph, ascending.

    All ``count`` rows when ``graph_size`` is 0 or not exceeded, else a seeded uniform
    subset of ``graph_size`` rows. A random subset, not the best by descriptor distance:
    on the dev pairs the best ranked over-represent repeated structure (pair 000008 with
    GEDI: the 1000 best give a 168 deg flip, 1000 random ones the right pose).
    """
    if graph_size <= 0 or count <= graph_size:
        return np.arange(count)
    return np.sort(np.random.default_rng(0).choice(count, size=graph_size, replace=False))


def compatibility_matrix(
    src: np.ndarray, dst: np.ndarray, threshold: float, compiled: bool | None = None
) -> sparse.csr_matrix:
    """
    First-order spatial compatibility of SC2-PCR (eq. 2) as a sparse matrix.

    ``SC_ij = max(0, 1 - c_ij^2 / d^2)`` with ``c_ij = | ||p_i - p_j|| - ||q_i - q_j|| |``
    and ``d = threshold``; only entries with ``c_ij < d`` (where ``SC_ij > 0``) are
    stored, so the sparsity pattern is the hard compatibility and
    ``SC_ij > 0.75`` is the tight one (``c_ij < d / 2``).  The diagonal is 1.

    Squared distances come from one small matrix product per row block of the
    upper triangle (``|x_i|^2 + |x_j|^2 - 2 x_i . x_j`` on centred coordinates).
    In float32 their absolute error is bounded by ``E = 4 eps R^2`` (``R`` the
    centred extent), which spoils short distances only: a distance ``D`` is off
    by at most ``min(sqrt(E), E / D)``.  Entries within ``2 sqrt(E)`` of the
    threshold are kept as candidates and those with a distance below
    ``max(4 sqrt(E), 100 E / d)`` are recomputed exactly, so every stored
    ``c_ij`` is within ``0.01 d`` of the exact value (KITTI, ``R = 60`` m:
    ``sqrt(E) = 4`` cm, recomputed below 0.28 m, error < 3 mm).  When
    ``2 sqrt(E)`` exceeds ``d``, float64 is used throughout.

    - ``src``: ``(K, 3)`` source points, metres.
    - ``dst``: ``(K, 3)`` target points, metres.
    - ``threshold``: compatibility threshold ``d`` in metres.
    - ``compiled``: None uses the numba kernel when available
      (:func:`~mlsemreg_ros.core.estimation.kernels.compatibility_upper`: one fused pass over
      the coordinate differences, float32; 70 against 141 ms of CPU at K = 7000). Its
      ``c_ij`` are exact to the float32 rounding of the difference, so an entry within a
      few millimetres of ``d`` may fall on the other side than in the blocked products.

    Returns ``(K, K)`` symmetric CSR matrix, float32 values in ``(0, 1]``, sorted indices.
    """
    count = src.shape[0]
    p = src - src.mean(axis=0)
    q = dst - dst.mean(axis=0)
    extent2 = float(max((p * p).sum(axis=1).max(), (q * q).sum(axis=1).max())) if count else 0.0
    dtype: type = np.float32
    error = 2.0 * np.sqrt(np.finfo(np.float32).eps * extent2)  # sqrt(E)
    if 2.0 * error > threshold:
        dtype, error = np.float64, 2.0 * np.sqrt(np.finfo(np.float64).eps * extent2)
    if use_compiled(compiled) and count:
        per_row, columns, values = kernels.compatibility_upper(
            np.ascontiguousarray(p.T, dtype=dtype),
            np.ascontiguousarray(q.T, dtype=dtype),
            threshold,
        )
        return _symmetric_from_upper(per_row, columns, values, count)
    margin, short = 2.0 * error, max(4.0 * error, 100.0 * error * error / threshold)
    left_p, right_p = _augmented(p, dtype)
    left_q, right_q = _augmented(q, dtype)
    block = int(np.clip(_BLAS_MAX_MNK // (5 * max(count, 1)), 1, count))
    dist_p = np.empty(block * count, dtype=dtype)
    dist_q = np.empty(block * count, dtype=dtype)
    cross = np.empty(block * count, dtype=dtype)
    mask = np.empty(block * count, dtype=bool)
    upper = np.triu(np.ones((block, block), dtype=bool), 1)
    candidate_limit = dtype(threshold + margin)
    scale = np.float32(1.0 / threshold)
    row_counts, columns, values = [], [], []
    for first in range(0, count, block):
        last = min(count, first + block)
        height, width = last - first, count - first
        size = height * width
        a = dist_p[:size].reshape(height, width)
        b = dist_q[:size].reshape(height, width)
        c = cross[:size].reshape(height, width)
        m = mask[:size].reshape(height, width)
        np.matmul(left_p[first:last], right_p[:, first:], out=a)  # squared distances
        np.matmul(left_q[first:last], right_q[:, first:], out=b)
        np.abs(a, out=a)  # rounding can make a tiny squared distance negative
        np.sqrt(a, out=a)
        np.abs(b, out=b)
        np.sqrt(b, out=b)
        np.subtract(a, b, out=c)
        np.abs(c, out=c)
        np.less(c, candidate_limit, out=m)
        m[:, :height] &= upper[:height, :height]  # strict upper triangle only
        flat = np.flatnonzero(m)
        value = c.ravel()[flat]
        inexact = np.flatnonzero(np.minimum(a.ravel()[flat], b.ravel()[flat]) < short)
        if inexact.size:  # short distances: recompute exactly
            i = flat[inexact] // width
            j = flat[inexact] - i * width + first
            i += first
            value[inexact] = np.abs(
                np.linalg.norm(p[i] - p[j], axis=1) - np.linalg.norm(q[i] - q[j], axis=1)
            )
        keep = value < threshold
        flat, value = flat[keep], value[keep].astype(np.float32, copy=False)
        row_start = np.arange(height + 1) * width
        per_row = np.diff(np.searchsorted(flat, row_start))
        row_counts.append(per_row)
        columns.append((flat - np.repeat(row_start[:-1] - first, per_row)).astype(np.int32))
        value *= scale
        np.square(value, out=value)
        np.subtract(np.float32(1.0), value, out=value)
        np.maximum(value, np.float32(1e-12), out=value)  # stored entries stay > 0
        values.append(value)
    return _symmetric_from_upper(
        np.concatenate(row_counts), np.concatenate(columns), np.concatenate(values), count
    )


def _symmetric_from_upper(
    upper_count: np.ndarray, col: np.ndarray, value: np.ndarray, count: int
) -> sparse.csr_matrix:
    """
    Symmetric CSR with unit diagonal from the strict upper triangle in CSR order.

    ``upper_count`` holds the entries per row; ``col`` and ``value`` the entries
    sorted by (row, column).
    """
    upper_indptr = np.zeros(count + 1, dtype=np.int64)
    np.cumsum(upper_count, out=upper_indptr[1:])
    upper = sparse.csr_matrix((value, col, upper_indptr), shape=(count, count))
    lower = upper.tocsc()  # CSC of the upper part = CSR of the lower part, sorted
    lower_count = np.diff(lower.indptr)
    indptr = np.zeros(count + 1, dtype=np.int64)
    np.cumsum(upper_count + lower_count + 1, out=indptr[1:])
    indices = np.empty(int(indptr[-1]), dtype=np.int32)
    data = np.empty(int(indptr[-1]), dtype=np.float32)
    # row i holds: its lower entries (cols < i), the diagonal, its upper entries (cols > i)
    diagonal_at = indptr[:-1] + lower_count
    indices[diagonal_at] = np.arange(count, dtype=np.int32)
    data[diagonal_at] = 1.0
    at = np.arange(col.size) + np.repeat(diagonal_at + 1 - upper_indptr[:-1], upper_count)
    indices[at] = col
    data[at] = value
    at = np.arange(lower.indices.size) + np.repeat(indptr[:-1] - lower.indptr[:-1], lower_count)
    indices[at] = lower.indices
    data[at] = lower.data
    matrix = sparse.csr_matrix((data, indices, indptr), shape=(count, count))
    matrix.has_sorted_indices = True
    return matrix


def leading_eigenvector(matrix: sparse.csr_matrix, iterations: int) -> tuple[np.ndarray, float]:
    """
    Leading eigenvector of a non-negative symmetric matrix by power iteration.

    As in SC2-PCR's reference code: start from ones, normalise every step,
    stop after ``iterations`` steps or when the vector no longer changes
    (``np.allclose``).

    Returns ``((K,) float64 unit vector, Rayleigh quotient v^T M v / v^T v)``.
    """
    vector = np.ones(matrix.shape[0], dtype=np.float32)
    for _ in range(iterations):
        new = matrix @ vector
        new /= np.linalg.norm(new) + 1e-6
        converged = np.allclose(new, vector)
        vector = new
        if converged:
            break
    vector = vector.astype(np.float64)
    norm2 = float(vector @ vector)
    eigenvalue = float(vector @ (matrix @ vector)) / norm2 if norm2 > 0 else 0.0
    return vector, eigenvalue


def pick_seeds(src: np.ndarray, scores: np.ndarray, radius: float, max_seeds: int) -> np.ndarray:
    """
    Seeds of SC2-PCR: local maxima of the eigenvector scores, best first.

    A correspondence is a local maximum when no correspondence whose source
    point lies closer than ``radius`` has a strictly higher score (ties keep
    both, as in the reference code).  Returns at most ``max_seeds`` indices,
    sorted by descending score (ties by index).
    """
    is_max = np.ones(scores.shape[0], dtype=bool)
    if radius > 0.0:
        pairs = cKDTree(src).query_pairs(np.nextafter(radius, 0.0), output_type='ndarray')
        if pairs.size:
            i, j = pairs[:, 0], pairs[:, 1]
            is_max[i[scores[i] < scores[j]]] = False
            is_max[j[scores[j] < scores[i]]] = False
    candidates = np.flatnonzero(is_max)
    order = np.argsort(-scores[candidates], kind='stable')
    return candidates[order[:max_seeds]]


def seed_hypotheses(
    src: np.ndarray,
    dst: np.ndarray,
    consensus: np.ndarray,
    valid: np.ndarray,
    k2: int,
    threshold: float,
    iterations: int,
) -> np.ndarray:
    """
    One rigid transform per seed from its consensus set (SC2-PCR Sec. 3.4).

    Second stage: among the ``k1`` candidates, keep the ``k2`` with the highest
    local SC2 score with the seed, ``(hard[seed] @ hard)`` restricted to the
    set (``hard = c < d``); ties keep the first-stage order.  Their local
    first-order compatibility ``max(0, 1 - c^2 / d^2)`` (zero diagonal) gives,
    by batched power iteration, the weights (normalised to sum 1) of a
    weighted SVD.

    - ``src``, ``dst``: ``(K, 3)`` correspondences, metres.
    - ``consensus``: ``(S, k1)`` indices, seed in column 0.
    - ``valid``: ``(S, k1)`` mask of real entries.
    - ``k2``: second-stage size (``<= k1``).
    - ``threshold``: compatibility threshold ``d``, metres.
    - ``iterations``: power iterations.

    Returns ``(S, 4, 4)`` transforms.
    """
    centre_src, centre_dst = src.mean(axis=0), dst.mean(axis=0)
    src32 = (src - centre_src).astype(np.float32)
    dst32 = (dst - centre_dst).astype(np.float32)
    pair_valid = valid[:, :, None] & valid[:, None, :]
    local_hard = (_cross_lengths(src32[consensus], dst32[consensus]) < threshold) & pair_valid
    hard = local_hard.astype(np.float32)
    score = (hard[:, :1, :] @ hard)[:, 0, :]  # local SC2 row of the seed
    score[~valid] = -1.0
    order = np.argsort(-score, axis=1, kind='stable')[:, :k2]
    fine = np.take_along_axis(consensus, order, axis=1)
    fine_valid = np.take_along_axis(valid, order, axis=1)
    cross = _cross_lengths(src32[fine], dst32[fine])
    local_sc = 1.0 - np.square(cross * np.float32(1.0 / threshold))
    np.maximum(local_sc, 0.0, out=local_sc)
    local_sc *= fine_valid[:, :, None] & fine_valid[:, None, :]
    local_sc[:, np.arange(k2), np.arange(k2)] = 0.0
    weights = _batched_leading_eigenvector(local_sc, iterations) * fine_valid
    weights /= weights.sum(axis=1, keepdims=True) + 1e-6
    transforms = weighted_rigid_transform(src[fine] - centre_src, dst[fine] - centre_dst, weights)
    # undo the centring: T = T(+c_dst) @ T_local @ T(-c_src)
    rotation = transforms[:, :3, :3]
    transforms[:, :3, 3] += centre_dst - rotation @ centre_src
    return transforms


def count_inliers(
    transforms: np.ndarray, src: np.ndarray, dst: np.ndarray, threshold: float
) -> np.ndarray:
    """
    Correspondences with residual below ``threshold`` per ``(S, 4, 4)`` hypothesis.

    ``||R p + t - q||^2`` is expanded into one matrix product of ``(S, 16)``
    hypothesis terms with ``(16, K)`` correspondence terms (float64).
    """
    count = src.shape[0]
    centre_src, centre_dst = src.mean(axis=0), dst.mean(axis=0)
    p, q = src - centre_src, dst - centre_dst
    rotation = transforms[:, :3, :3]
    translation = transforms[:, :3, 3] + rotation @ centre_src - centre_dst  # centred frames
    # |Rp|^2 + |t|^2 + |q|^2 + 2 t.Rp - 2 t.q - 2 q.Rp, with |Rp| = |p|
    hyp = np.concatenate(
        [
            np.ones((len(transforms), 1)),
            (translation * translation).sum(axis=1, keepdims=True),
            2.0 * (rotation.transpose(0, 2, 1) @ translation[:, :, None])[:, :, 0],
            -2.0 * translation,
            -2.0 * rotation.reshape(-1, 9),
        ],
        axis=1,
    )
    corr = np.concatenate(
        [
            ((p * p).sum(axis=1) + (q * q).sum(axis=1))[None, :],
            np.ones((1, count)),
            p.T,
            q.T,
            (q[:, :, None] * p[:, None, :]).reshape(count, 9).T,  # q_a p_b, matches R_ab
        ],
        axis=0,
    )
    corr = np.ascontiguousarray(corr)
    # square-ish blocks of single-threaded products (small blocks mostly pack operands)
    rows = int(np.clip(np.sqrt(_BLAS_MAX_MNK / hyp.shape[1]), 1, transforms.shape[0]))
    cols = max(1, _BLAS_MAX_MNK // (hyp.shape[1] * rows))
    limit = threshold * threshold
    counts = np.zeros(transforms.shape[0], dtype=np.int64)
    for first in range(0, transforms.shape[0], rows):
        block_rows = slice(first, first + rows)
        block = hyp[block_rows]
        for start in range(0, count, cols):
            squared = block @ corr[:, slice(start, start + cols)]
            counts[block_rows] += np.count_nonzero(squared < limit, axis=1)
    return counts


def post_refinement(
    transform: np.ndarray,
    src: np.ndarray,
    dst: np.ndarray,
    threshold: float,
    iterations: int,
    stop: Callable[[np.ndarray], bool] | None = None,
) -> tuple[np.ndarray, int]:
    """
    Reweighted least squares on the inliers of ``transform`` (SC2-PCR post-refinement).

    Each step takes the correspondences with residual ``r < threshold`` and
    re-estimates with weights ``1 / (1 + (r / threshold)^2)``; it stops when the
    inlier count no longer changes, after ``iterations`` steps, when fewer
    than three inliers remain, or when ``stop(transform)`` (if given) is true after a
    step (hypothesis verification: the pose has joined one already refined).

    Returns ``(refined (4, 4) transform, re-estimations done)``.
    """
    previous = -1
    done = 0
    for _ in range(iterations):
        residual = residuals(transform, src, dst)
        inliers = residual < threshold
        n_inliers = int(np.count_nonzero(inliers))
        if n_inliers == previous or n_inliers < 3:
            break
        previous = n_inliers
        weights = 1.0 / (1.0 + (residual[inliers] / threshold) ** 2)
        transform = weighted_rigid_transform(src[inliers], dst[inliers], weights)
        done += 1
        if stop is not None and stop(transform):
            break
    return transform, done


def _augmented(points: np.ndarray, dtype: type) -> tuple[np.ndarray, np.ndarray]:
    """``(K, 5)`` and ``(5, K)`` factors whose product is the squared distance matrix."""
    norms = (points * points).sum(axis=1)
    ones = np.ones_like(norms)
    left = np.column_stack([-2.0 * points, norms, ones]).astype(dtype)
    right = np.ascontiguousarray(np.column_stack([points, ones, norms]).T.astype(dtype))
    return left, right


def _cross_lengths(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """``(S, n, n)`` length consistency ``c_ij`` within each of ``S`` sets of ``n`` pairs."""
    # sets along the last axis: every broadcast operation runs over S contiguous values
    # (with the sets first, NumPy's inner loops would be n long: 3x slower for n = 30)
    lengths = []
    for points in (src, dst):
        axes = np.ascontiguousarray(np.moveaxis(points, (0, 2), (2, 0)))  # (3, n, S)
        squared = None
        for axis in axes:
            diff = axis[:, None, :] - axis[None, :, :]  # (n, n, S)
            diff *= diff
            if squared is None:
                squared = diff
            else:
                squared += diff
        lengths.append(np.sqrt(squared, out=squared))
    cross = lengths[0]
    cross -= lengths[1]
    np.abs(cross, out=cross)
    return np.ascontiguousarray(np.moveaxis(cross, 2, 0))  # (S, n, n)


def _batched_leading_eigenvector(matrices: np.ndarray, iterations: int) -> np.ndarray:
    """``(S, n)`` leading eigenvectors of ``(S, n, n)`` matrices by power iteration."""
    vector = np.ones((*matrices.shape[:2], 1), dtype=matrices.dtype)
    for _ in range(iterations):
        new = matrices @ vector
        new /= np.linalg.norm(new, axis=1, keepdims=True) + 1e-6
        converged = np.allclose(new, vector)
        vector = new
        if converged:
            break
    return vector[:, :, 0]


def _ms(start: float) -> float:
    return 1e3 * (time.perf_counter() - start)

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
SC2-PCR's second-order compatibility of the seeds, and the CPU work budget of that stage.

The stage 3 of :mod:`mlsemreg_ros.core.estimation.sc2pcr` (Chen et al., CVPR 2022, eq. 4):
``SC2 = hard ⊙ (tight @ tight)`` with ``tight_ij = c_ij < d / 2``, counted for the seed rows
only, without a sparse matrix product: correspondences compatible with many seeds as packed
bit sets, the rest by enumeration (:func:`second_order_compatibility`); then the consensus
set of each seed (:func:`seed_consensus_sets`). A cost model (``_SC2_BUDGET_NS``) keeps
only the best-scored seeds that fit the budget ``estimator.second_order_budget``.
"""

from __future__ import annotations

from mlsemreg_ros.core.estimation.config import EstimatorConfig
import numpy as np
from scipy import sparse

#: Cost model of the SC2 computation in nanoseconds (measured on a 2-core Xeon):
#: one enumerated ``(s, k, j)`` triple, one 64-bit AND + popcount, one candidate
#: pair (gathers, ranking).  It splits the SC2 sum between enumeration and bit
#: sets (see :func:`second_order_compatibility`) and sizes the seed budget.
_ENUMERATION_COST = 5.0
_BIT_COST = 3.0 / 64.0
_PAIR_COST = 30.0

#: SC2 work budget in cost-model nanoseconds (about 100 ms of real work on a
#: 2-core Xeon).  SC2-PCR's reference code runs on a GPU; on a CPU the SC2 rows
#: of ``seed_ratio * K`` seeds cost up to seconds when the compatibility is dense
#: (inlier-rich input, e.g. ML-SemReg correspondences).  Then only the best-scored
#: seeds that fit are kept (never fewer than ``_MIN_SEEDS``); the diagnostics
#: report ``n_seeds_nms`` (before) and ``n_seeds`` (after).  On the 10 KITTI dev
#: pairs fewer seeds (down to 1 %) changed no registration.
_SC2_BUDGET_NS = EstimatorConfig().second_order_budget * 1e6  # estimator.second_order_budget
_MIN_SEEDS = 64

#: uint64 words per chunk of the bit-set part of the SC2 computation.
_BIT_CHUNK_WORDS = 65_536

#: Entries of the per-chunk ``(seeds, K)`` count table of the enumerated SC2 part.
_LIGHT_TABLE_ENTRIES = 262_144

#: ``tight = c < d / 2`` in terms of ``SC = 1 - c^2 / d^2``: ``SC > 1 - 1/4``.
_TIGHT_SC = 0.75


def tight_compatibility(sc: sparse.csr_matrix) -> sparse.csr_matrix:
    """``(K, K)`` int8 CSR of ``tight = c < d / 2`` (``SC > 0.75``), diagonal included."""
    tight = sc.copy()
    tight.data = (sc.data > _TIGHT_SC).astype(np.int8)
    tight.eliminate_zeros()
    return tight


def second_order_cost(
    sc: sparse.csr_matrix, tight: sparse.csr_matrix, seeds: np.ndarray
) -> np.ndarray:
    """
    Cost-model estimate (ns) of :func:`second_order_compatibility` for every seed prefix.

    Returns ``(S,)``: entry ``m`` is the cost for ``seeds[:m + 1]``.  Every ``k``
    costs the cheaper of enumeration (``seeds near k x degree(k)`` triples) and
    one bit per candidate pair; every pair has a fixed cost.  Evaluated at
    powers of two and interpolated in between (the cost grows with the prefix).
    """
    n_seeds = seeds.size
    pairs = np.cumsum(sc.indptr[seeds + 1] - sc.indptr[seeds]).astype(np.float64)
    degree = np.diff(tight.indptr).astype(np.float64)
    seed_rows = tight[seeds]
    sizes = np.unique(np.minimum(n_seeds, 2 ** np.arange(int(np.log2(n_seeds)) + 2)))
    cost = np.empty(sizes.size)
    for at, size in enumerate(sizes):
        near = np.bincount(seed_rows.indices[: seed_rows.indptr[size]], minlength=sc.shape[0])
        per_k = np.minimum(near * degree * _ENUMERATION_COST, pairs[size - 1] * _BIT_COST)
        cost[at] = per_k.sum() + pairs[size - 1] * _PAIR_COST
    return np.interp(np.arange(1, n_seeds + 1), sizes, cost)


def budget_seeds(
    sc: sparse.csr_matrix,
    tight: sparse.csr_matrix,
    seeds: np.ndarray,
    budget_ns: float | None = None,
) -> np.ndarray:
    """
    Longest prefix of ``seeds`` (best first) whose SC2 cost fits ``budget_ns``.

    The budget defaults to ``_SC2_BUDGET_NS``.  Never fewer than ``_MIN_SEEDS``
    seeds (or all of them when there are fewer).
    """
    if budget_ns is None:
        budget_ns = _SC2_BUDGET_NS
    if seeds.size <= _MIN_SEEDS:
        return seeds
    cost = second_order_cost(sc, tight, seeds)
    count = max(_MIN_SEEDS, int(np.searchsorted(cost, budget_ns, side='right')))
    return seeds[:count]


def second_order_compatibility(
    sc: sparse.csr_matrix, seeds: np.ndarray, tight: sparse.csr_matrix | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Second-order compatibility of the seed rows (SC2-PCR eq. 4), where it can be non-zero.

    ``SC2[s, j] = hard[s, j] * sum_k tight[s, k] tight[k, j]``: the number of
    correspondences tightly compatible (``c < d / 2``) with both ``s`` and ``j``,
    for the pairs ``(s, j)`` that are hard-compatible (``c < d``).

    The sum over ``k`` is split by cost.  Correspondences ``k`` tight with many
    seeds and many others (the inlier cluster) are handled as bit sets: one
    AND + popcount per 64 of them for every pair.  The remaining ``k`` (mostly
    outliers with small neighbourhoods) are enumerated: every seed ``s`` and
    every ``j`` in ``tight(k)`` give one count to the pair ``(s, j)``.

    - ``sc``: ``(K, K)`` first-order compatibility from :func:`compatibility_matrix`.
    - ``seeds``: ``(S,)`` seed indices.
    - ``tight``: :func:`tight_compatibility` of ``sc`` if already computed.

    Returns ``(seed_position (P,), column (P,), sc2 (P,) int64)`` for every pair
    ``(seeds[seed_position], column)`` with ``hard = 1``, sorted by ``(seed_position,
    column)``; ``sc2`` may be 0.
    """
    count, n_seeds = sc.shape[0], seeds.size
    hard_seeds = sc[seeds]
    hard_seeds.sort_indices()
    pair_row = np.repeat(np.arange(n_seeds), np.diff(hard_seeds.indptr))
    pair_col = hard_seeds.indices.astype(np.int64)
    n_pairs = pair_col.size
    sc2 = np.zeros(n_pairs, dtype=np.int64)
    if tight is None:
        tight = tight_compatibility(sc)
    degree = np.diff(tight.indptr)
    is_seed = np.zeros(count, dtype=np.int32)
    is_seed[seeds] = 1
    seeds_near = tight @ is_seed  # seeds among tight(k)
    # cost per k: enumeration seeds_near * degree vs one bit per pair
    heavy = seeds_near * degree * _ENUMERATION_COST > n_pairs * _BIT_COST
    heavy &= seeds_near > 0
    heavy_ids = np.flatnonzero(heavy)
    if heavy_ids.size:
        sc2 += _heavy_counts(tight, heavy_ids, seeds, pair_row, pair_col)
    light_ids = np.flatnonzero(~heavy & (seeds_near > 0))
    if light_ids.size:
        sc2 += _light_counts(tight, light_ids, seeds, hard_seeds.indptr, pair_row, pair_col)
    return pair_row, pair_col, sc2


def _heavy_counts(
    tight: sparse.csr_matrix,
    heavy_ids: np.ndarray,
    seeds: np.ndarray,
    pair_row: np.ndarray,
    pair_col: np.ndarray,
) -> np.ndarray:
    """``sum_{k heavy} tight[s, k] tight[k, j]`` per pair, with packed bit sets."""
    count = tight.shape[0]
    words = (heavy_ids.size + 63) // 64
    columns = tight[:, heavy_ids].tocoo()
    dense = np.zeros((count, 64 * words), dtype=bool)
    dense[columns.row, columns.col] = True
    bits = np.packbits(dense, axis=1, bitorder='little').view(np.uint64)  # (K, words)
    # one opaque item per row makes the row gathers plain copies
    row_type = np.dtype((np.void, 8 * words))
    rows = bits.view(row_type).ravel()
    seed_rows = rows[seeds]
    ones = np.ones(words, dtype=np.float32)
    counts = np.empty(pair_col.size, dtype=np.int64)
    chunk = max(1, _BIT_CHUNK_WORDS // words)
    for first in range(0, pair_col.size, chunk):
        window = slice(first, first + chunk)
        both = seed_rows[pair_row[window]].view(np.uint64)
        both &= rows[pair_col[window]].view(np.uint64)
        popcount = np.bitwise_count(both).reshape(-1, words).astype(np.float32)
        counts[window] = popcount @ ones  # exact below 2^24
    return counts


def _light_counts(
    tight: sparse.csr_matrix,
    light_ids: np.ndarray,
    seeds: np.ndarray,
    pair_indptr: np.ndarray,
    pair_row: np.ndarray,
    pair_col: np.ndarray,
) -> np.ndarray:
    """
    ``sum_{k light} tight[s, k] tight[k, j]`` per pair, by enumerating ``(s, k, j)``.

    Seeds are processed in chunks whose ``(chunk, K)`` count table stays in cache.
    """
    count = tight.shape[0]
    is_light = np.zeros(count, dtype=bool)
    is_light[light_ids] = True
    seed_rows = tight[seeds]  # entries (s, k) of the seed rows, k light
    entry_seed = np.repeat(np.arange(seeds.size), np.diff(seed_rows.indptr))
    entry_k = seed_rows.indices
    light = is_light[entry_k]
    entry_seed, entry_k = entry_seed[light], entry_k[light]
    entry_indptr = np.searchsorted(entry_seed, np.arange(seeds.size + 1))
    counts = np.zeros(pair_col.size, dtype=np.int64)
    rows_per_chunk = max(1, _LIGHT_TABLE_ENTRIES // count)
    for first in range(0, seeds.size, rows_per_chunk):
        last = min(seeds.size, first + rows_per_chunk)
        e0, e1 = entry_indptr[first], entry_indptr[last]
        expanded = tight[entry_k[e0:e1]]  # rows tight(k), concatenated
        key = np.repeat((entry_seed[e0:e1] - first) * count, np.diff(expanded.indptr))
        key += expanded.indices
        table = np.bincount(key, minlength=(last - first) * count)
        p0, p1 = pair_indptr[first], pair_indptr[last]
        counts[p0:p1] = table[(pair_row[p0:p1] - first) * count + pair_col[p0:p1]]
    return counts


def seed_consensus_sets(
    sc: sparse.csr_matrix, seeds: np.ndarray, k1: int, tight: sparse.csr_matrix | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """
    First-stage consensus sets: the ``k1`` most SC2-compatible correspondences per seed.

    The seed itself comes first; the others follow by descending SC2 (eq. 4,
    see :func:`second_order_compatibility`), ties by index.  Correspondences
    with ``SC2 = 0`` are never chosen: short rows are padded and masked.

    Returns ``(consensus (S, k1) int64 indices, valid (S, k1) bool)``.
    """
    count, n_seeds = sc.shape[0], seeds.size
    row, col, value = second_order_compatibility(sc, seeds, tight)
    keep = (value > 0) & (col != seeds[row])
    row, col, value = row[keep], col[keep], value[keep]
    consensus = np.repeat(seeds[:, None], k1, axis=1).astype(np.int64)
    valid = np.zeros((n_seeds, k1), dtype=bool)
    valid[:, 0] = True
    if row.size == 0 or k1 < 2:
        return consensus, valid
    # unique score per row: value descending, then index ascending
    score = value * (count + 1) + (count - col)
    # rows are contiguous and sorted: lay them out as a padded (S, longest) table
    row_start = np.searchsorted(row, np.arange(n_seeds + 1))
    length = np.diff(row_start)
    table = np.full((n_seeds, int(length.max())), -1, dtype=np.int64)
    table[row, np.arange(row.size) - row_start[row]] = score
    take = min(k1 - 1, table.shape[1])
    if take < table.shape[1]:
        top = np.argpartition(-table, take - 1, axis=1)[:, :take]
        top_score = np.take_along_axis(table, top, axis=1)
    else:
        top_score = table
    top_score = -np.sort(-top_score, axis=1)
    chosen = top_score >= 0
    kept = slice(1, 1 + take)
    consensus[:, kept][chosen] = (count - top_score % (count + 1))[chosen]
    valid[:, kept] = chosen
    return consensus, valid

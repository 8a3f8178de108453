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
The search of the matcher: descriptor nearest neighbours under the Mask Matching masks.

The engine of :func:`mlsemreg_ros.core.matching.matching.semantic_match` (paper eq. 6-8; the steps
are listed in that module's docstring): the scene similarity built per chunk of source
rows from the targets' BMR-SS patterns, the sparse candidates of the restrictive rows
(:func:`_masked_candidates`), the dense nearest neighbours of the permissive ones
(:func:`_dense_group_nn`), packed ``(distance, index)`` keys, and the shared worker pool
with BLAS pinned to one thread while it runs.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass
import os
import threading
import time
from typing import Any

from mlsemreg_ros.core import threads
from mlsemreg_ros.core.results import Correspondences
from mlsemreg_ros.core.threads import LazyPool
import numpy as np
import scipy.sparse as sp

try:  # optional: pins BLAS to one thread while the matcher's own threads run
    from threadpoolctl import ThreadpoolController
except ImportError:  # pragma: no cover
    ThreadpoolController = None

NO_MATCH = np.uint64(0xFFFFFFFFFFFFFFFF)
_LOW32 = np.uint64(0xFFFFFFFF)
_DENSE_BLOCK_ELEMENTS = 2_000_000  # rows x targets per dense distance block
_CHUNK_ELEMENTS = 600_000  # rows x target patterns per Mask Matching chunk (cache sized)
_DENSE_FRACTION = 0.1  # candidate share of a chunk above which it is resolved densely
_POOL = LazyPool('mlsemreg-match')  # shared by all calls
_BLAS: Any = None  # threadpoolctl controller, created on first use
_BLAS_LOCK = threading.Lock()


def _forget_blas() -> None:
    """In a forked child, build the threadpoolctl controller afresh."""
    global _BLAS, _BLAS_LOCK
    _BLAS, _BLAS_LOCK = None, threading.Lock()


os.register_at_fork(after_in_child=_forget_blas)


def _masked_candidates(
    src: np.ndarray,
    dst: np.ndarray,
    row_in_group: np.ndarray,
    col_in_group: np.ndarray,
    source_bmr: np.ndarray,
    target_bmr: np.ndarray,
    top_k: int,
    fwd: np.ndarray,
    bwd: np.ndarray | None,
    diagnostics: dict[str, Any] | None,
) -> np.ndarray:
    """
    Run steps 2-3 group by group; return the (M, G) mask of restrictive (row, group) pairs.

    Group g only touches its own rows R_g and targets C_g (sum_g |R_g| |C_g| is about 2/3
    of |P| |Q| on KITTI). Targets with the same BMR-SS have the same column of S, so S, its
    row maxima and the mask are computed once per distinct target BMR-SS ("pattern", about
    half of the targets at 5000 keypoints) and the candidates are expanded to targets
    afterwards. Source rows are ordered by BMR-SS so that a chunk holds neighbouring
    keypoints, whose candidates share targets: the descriptor GEMM of a chunk runs on those
    targets only. Tasks (group, row chunk) are independent (each writes only its own
    (row, group) slots of ``fwd``), so they run on a small thread pool; NumPy and BLAS
    release the GIL in these kernels.
    """
    num_rows, num_groups = row_in_group.shape
    bits, width = _padded_bins(source_bmr)
    # S <= set bins of a source row; uint8 holds it (255 = "no threshold") below 255.
    s_type = np.uint8 if width.max(initial=0) < 255 else np.uint16
    pattern_of, pattern_bins = _target_patterns(target_bmr, s_type)
    # neighbouring keypoints have similar BMR-SS: order the rows by their first set bins
    num_bins = source_bmr.shape[1]
    key = np.zeros(num_rows, dtype=np.int64)
    for k in range(min(3, bits.shape[1])):
        key = key * (num_bins + 1) + bits[:, k]
    row_order = np.argsort(key, kind='stable')
    col_order = np.argsort(pattern_of, kind='stable')  # targets grouped by pattern
    dst_sq = _sq_norms(dst)
    context = _MaskContext(
        src=src,
        src_sq=_sq_norms(src),
        bits=bits,
        width=width,
        top_k=top_k,
        none=int(np.iinfo(s_type).max),
        s_type=s_type,
        restrictive=np.zeros((num_rows, num_groups), dtype=bool),
        fwd=fwd,
        num_groups=num_groups,
        mutual=bwd is not None,
    )
    rows_in = np.asfortranarray(row_in_group[row_order])  # (M, G), columns contiguous
    cols_in = np.asfortranarray(col_in_group[col_order])
    tasks = []
    for g in range(num_groups):  # groups, not points
        rows = row_order[rows_in[:, g]]
        cols = col_order[cols_in[:, g]]  # pattern u: cols[start[u]:start[u+1]]
        if len(rows) == 0 or len(cols) == 0:
            continue
        patterns = pattern_of[cols]
        start = np.flatnonzero(np.r_[True, patterns[1:] != patterns[:-1]])
        group = _MaskGroup(
            index=g,
            cols=cols,
            dst=dst[cols],
            dst_sq=dst_sq[cols],
            bins=np.take(pattern_bins, patterns[start], axis=1),
            start=start,
            count=np.diff(np.r_[start, len(cols)]),
        )
        # rows x patterns bounds the mask work, rows x targets the descriptor GEMM
        step = max(1, min(_CHUNK_ELEMENTS // len(start), _DENSE_BLOCK_ELEMENTS // len(cols)))
        tasks += [(group, rows[slice(lo, lo + step)]) for lo in range(0, len(rows), step)]
    results = _run_tasks(lambda task: _masked_chunk(context, *task), tasks)
    if bwd is not None and results:
        slots = np.concatenate([r[0] for r in results])
        np.minimum.at(bwd, slots, np.concatenate([r[1] for r in results]))
    if diagnostics is not None:
        diagnostics['mask_candidates'] = int(sum(r[2] for r in results))
    return context.restrictive


def _padded_bins(bmr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """
    Set bins of every BMR-SS row, (M, W) padded with the zero bin T*N, and (M,) counts.

    Row i of S is then the sum over k of the target bin rows ``bits[i, k]`` (eq. 6).
    """
    flat = np.flatnonzero(bmr)  # (2-D np.nonzero is about twice as slow)
    rows = flat // max(bmr.shape[1], 1)
    bins = flat - rows * bmr.shape[1]
    width = np.bincount(rows, minlength=bmr.shape[0])
    bits = np.full((bmr.shape[0], max(int(width.max(initial=0)), 1)), bmr.shape[1], dtype=np.intp)
    bits[rows, np.arange(len(rows)) - (np.cumsum(width) - width)[rows]] = bins
    return bits, width


def _target_patterns(bmr: np.ndarray, s_type: type) -> tuple[np.ndarray, np.ndarray]:
    """
    Distinct BMR-SS rows ("patterns") of the targets: (M',) pattern id, (T*N + 1, P) bins.

    The bin table has one column per pattern and a last, all-zero bin row (the padding).
    """
    packed = np.packbits(bmr, axis=1)
    words = np.zeros((len(bmr), max(8, -(-packed.shape[1] // 8) * 8)), dtype=np.uint8)
    words[:, : packed.shape[1]] = packed
    words = words.view(np.uint64)  # (M', ceil(T*N / 64)) exact row keys
    order = np.lexsort(words.T)
    new = np.r_[True, (words[order[1:]] != words[order[:-1]]).any(axis=1)]
    pattern_of = np.empty(len(bmr), dtype=np.intp)
    pattern_of[order] = np.cumsum(new) - 1
    table = np.zeros((bmr.shape[1] + 1, int(new.sum())), dtype=s_type)
    table[:-1] = bmr[order[new]].T
    return pattern_of, table


@dataclass
class _MaskContext:
    """Read-only inputs (and disjoint outputs) shared by the tasks of Mask Matching."""

    src: np.ndarray  # (M, D) float32
    src_sq: np.ndarray  # (M,)
    bits: np.ndarray  # (M, W) set bins of each source BMR-SS row, padded with T*N
    width: np.ndarray  # (M,) set bins per row
    top_k: int
    none: int
    s_type: type
    restrictive: np.ndarray  # (M, G) bool, written per (row, group)
    fwd: np.ndarray  # (M * G,) packed winners, written per (row, group)
    num_groups: int
    mutual: bool


@dataclass
class _MaskGroup:
    """One matching group's targets, sorted by BMR-SS pattern, and the patterns' bins."""

    index: int
    cols: np.ndarray  # (C,) positions in the sorted targets, grouped by pattern
    dst: np.ndarray  # (C, D) float32
    dst_sq: np.ndarray  # (C,)
    bins: np.ndarray  # (T*N + 1, P) BMR-SS of the group's P patterns by bin; last row zero
    start: np.ndarray  # (P,) first position in cols of each pattern
    count: np.ndarray  # (P,) targets of each pattern


def _masked_chunk(
    ctx: _MaskContext, group: _MaskGroup, rows: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int]:
    """Mask Matching of source ``rows`` in one group: S, threshold, candidates, winners."""
    bits = ctx.bits[rows, : max(int(ctx.width[rows].max()), 1)]  # padded with the zero bin
    similarity = group.bins[bits[:, 0]]  # (R, P) scene similarity S per pattern, eq. 6
    for k in range(1, bits.shape[1]):  # set bins, not points
        similarity += group.bins[bits[:, k]]
    # T = m_s(i) - (K - 1); a (row, group) is restrictive iff T >= 1
    threshold = similarity.max(axis=1).astype(np.int32) - (ctx.top_k - 1)
    strict = threshold >= 1
    ctx.restrictive[rows, group.index] = strict
    if not strict.any():
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.uint64), 0
    threshold = np.where(strict, threshold, ctx.none).astype(ctx.s_type)
    mask = similarity >= threshold[:, None]
    flat = np.flatnonzero(mask)  # row-major: grouped by row
    row_start = np.searchsorted(flat, np.arange(len(rows) + 1) * mask.shape[1])
    r = np.repeat(np.arange(len(rows)), np.diff(row_start))
    u = flat - r * mask.shape[1]
    count = group.count[u]
    if count.sum() > _DENSE_FRACTION * len(rows) * len(group.cols):  # weak landmark evidence
        return _masked_chunk_dense(ctx, group, rows, mask)
    # expand (row, pattern) to (row, target): pattern u holds cols[start[u]:start[u] + count[u]]
    r = np.repeat(r, count)
    ends = np.cumsum(count)
    c = np.arange(len(r)) + np.repeat(group.start[u] - (ends - count), count)
    per_row = np.bincount(r, minlength=len(rows))
    # ||a - b||^2 = ||a||^2 + ||b||^2 - 2 a.b: one GEMM on the targets that are candidates
    # of some row of the chunk (few: the rows are neighbours), read at the candidates
    used = np.repeat(mask.any(axis=0), group.count)
    slot_of_col = np.cumsum(used) - 1
    inner = ctx.src[rows] @ group.dst[used].T  # (R, U)
    dist_sq = inner.reshape(-1)[r * inner.shape[1] + slot_of_col[c]]
    dist_sq *= -2.0
    dist_sq += ctx.src_sq[rows][r] + group.dst_sq[c]
    np.maximum(dist_sq, 0.0, out=dist_sq)
    keys = _pack(dist_sq, group.cols[c])
    winners = per_row > 0
    slots = rows[winners] * ctx.num_groups + group.index
    ctx.fwd[slots] = np.minimum.reduceat(keys, (np.cumsum(per_row) - per_row)[winners])
    if not ctx.mutual:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.uint64), len(r)
    return (group.cols[c] * ctx.num_groups + group.index, _pack(dist_sq, rows[r]), len(r))


def _masked_chunk_dense(
    ctx: _MaskContext, group: _MaskGroup, rows: np.ndarray, mask: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int]:
    """
    Winners of :func:`_masked_chunk` from the dense (R, P) pattern mask, for many candidates.

    Used when thin landmark evidence makes a large share of the targets candidates, where
    gathering them one by one costs more than a few passes over the whole chunk. Same
    distances and the same winners as the sparse path: rows and targets are put in
    ascending index order, so ``argmin``'s first minimum is the smallest packed key.
    """
    by_index = np.argsort(group.cols)
    cols = group.cols[by_index]
    row_order = np.argsort(rows)
    rows, mask = rows[row_order], mask[row_order]
    candidate = np.take(
        mask, np.repeat(np.arange(len(group.count)), group.count)[by_index], axis=1
    )  # C order (mask[:, idx] would be F order: slow below)
    dist_sq = ctx.src[rows] @ group.dst[by_index].T  # (R, C)
    dist_sq *= -2.0
    dist_sq += ctx.src_sq[rows][:, None] + group.dst_sq[by_index][None, :]
    np.maximum(dist_sq, 0.0, out=dist_sq)
    if not np.isfinite(dist_sq.max()):  # NaN/inf: the bit trick below needs finite values
        return _masked_keys_dense(ctx, group.index, rows, cols, candidate, dist_sq)
    # non-negative floats sort like their int32 bits; a non-candidate gets the exponent bits
    # of inf set, which puts it above every finite distance (branch-free masking)
    key = dist_sq.view(np.int32)
    off = candidate.view(np.uint8).astype(np.int32)
    off -= 1
    off &= 0x7F800000
    key |= off
    has = np.flatnonzero(mask.any(axis=1))
    best = key.argmin(axis=1)[has]
    ctx.fwd[rows[has] * ctx.num_groups + group.index] = _pack(dist_sq[has, best], cols[best])
    candidates = int(np.count_nonzero(candidate))
    if not ctx.mutual:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.uint64), candidates
    hit = np.flatnonzero(candidate.any(axis=0))
    best_row = key[:, hit].argmin(axis=0)
    return (
        cols[hit] * ctx.num_groups + group.index,
        _pack(dist_sq[best_row, hit], rows[best_row]),
        candidates,
    )


def _masked_keys_dense(
    ctx: _MaskContext,
    group_index: int,
    rows: np.ndarray,
    cols: np.ndarray,
    candidate: np.ndarray,
    dist_sq: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Winners of a dense chunk by packed keys (any float, NaN and inf included)."""
    high = dist_sq.view(np.uint32).astype(np.uint64) << np.uint64(32)
    best = np.where(candidate, high | cols.astype(np.uint64), NO_MATCH).min(axis=1)
    winners = best != NO_MATCH
    ctx.fwd[rows[winners] * ctx.num_groups + group_index] = best[winners]
    candidates = int(np.count_nonzero(candidate))
    if not ctx.mutual:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.uint64), candidates
    back = np.where(candidate, high | rows.astype(np.uint64)[:, None], NO_MATCH).min(axis=0)
    hit = back != NO_MATCH
    return cols[hit] * ctx.num_groups + group_index, back[hit], candidates


def _dense_bits(bmr: np.ndarray | sp.spmatrix) -> np.ndarray:
    """BMR-SS as a dense (M, T*N) bool array; a nonzero entry is a set bit."""
    if sp.issparse(bmr):
        bmr = bmr.toarray()
    bmr = np.asarray(bmr)
    return bmr if bmr.dtype == bool else bmr != 0


def _run_tasks(function: Callable[[Any], Any], tasks: list[Any]) -> list[Any]:
    """
    ``[function(t) for t in tasks]`` on a small, persistent thread pool, BLAS single-threaded.

    The chunk GEMMs are small: multithreaded BLAS on them (and inside worker threads) was
    measured 3x slower, so BLAS runs single-threaded here and the chunks use the cores.
    """
    workers = max(1, min(len(tasks), threads.workers()))
    if ThreadpoolController is None or workers == 1:
        with _single_threaded_blas():
            return [function(task) for task in tasks]
    with _single_threaded_blas():
        return _POOL.run(function, tasks)


def _single_threaded_blas() -> AbstractContextManager:
    """Limit BLAS to one thread (threadpoolctl; the controller is built once, ~1 ms)."""
    global _BLAS
    if ThreadpoolController is None:
        return nullcontext()
    with _BLAS_LOCK:
        if _BLAS is None:
            _BLAS = ThreadpoolController()
    return _BLAS.limit(limits=1, user_api='blas')


def _dense_group_nn(
    src: np.ndarray,
    dst: np.ndarray,
    row_groups: np.ndarray,
    col_in_group: np.ndarray,
    fwd: np.ndarray,
    bwd: np.ndarray | None,
) -> None:
    """
    Unmasked nearest neighbours inside every group for the (row, group) pairs given.

    Blocks of rows (group, rows) are independent and run on the matcher's thread pool.
    """
    num_groups = row_groups.shape[1]
    src_sq, dst_sq = _sq_norms(src), _sq_norms(dst)
    tasks = []
    for g in range(num_groups):  # groups, not points
        rows = np.flatnonzero(row_groups[:, g])
        cols = np.flatnonzero(col_in_group[:, g])
        if len(rows) == 0 or len(cols) == 0:
            continue
        targets = (cols, dst[cols], dst_sq[cols], g)
        step = max(1, _DENSE_BLOCK_ELEMENTS // len(cols))
        tasks += [(targets, rows[slice(lo, lo + step)]) for lo in range(0, len(rows), step)]
    mutual = bwd is not None

    def block(
        task: tuple[tuple[np.ndarray, np.ndarray, np.ndarray, int], np.ndarray],
    ) -> tuple[np.ndarray, ...]:
        (cols, targets, targets_sq, g), part_rows = task
        minus_two_inner = src[part_rows] @ targets.T
        minus_two_inner *= -2.0
        # argmin_j ||a - b_j||^2 = argmin_j (||b_j||^2 - 2 a.b_j): ||a||^2 only for winners
        score = minus_two_inner + targets_sq[None, :]
        best = score.argmin(axis=1)
        row_dist = score[np.arange(len(part_rows)), best] + src_sq[part_rows]
        out = (part_rows * num_groups + g, _pack(row_dist, cols[best]))
        if not mutual:
            return out
        score = np.add(minus_two_inner, src_sq[part_rows, None], out=minus_two_inner)
        best_row = score.argmin(axis=0)
        col_dist = score[best_row, np.arange(len(cols))] + targets_sq
        return (*out, cols * num_groups + g, _pack(col_dist, part_rows[best_row]))

    for result in _run_tasks(block, tasks):  # fwd slots are disjoint; bwd takes the minimum
        fwd[result[0]] = result[1]
        if mutual:
            np.minimum.at(bwd, result[2], result[3])


def _exact_distance(
    source: np.ndarray, target: np.ndarray, rows: np.ndarray, cols: np.ndarray
) -> np.ndarray:
    """
    ||d_i - d_j|| of the selected pairs, in float64, returned as float32.

    Selection uses the GEMM form ||a||^2 + ||b||^2 - 2 a.b, whose last bits depend on the
    BLAS blocking; the reported distance is recomputed directly so that it is the same for
    any chunking or thread count (and equals SciPy's cdist to float32 rounding).
    """
    diff = np.asarray(source, dtype=np.float64)[rows] - np.asarray(target, dtype=np.float64)[cols]
    return np.sqrt(np.einsum('ij,ij->i', diff, diff)).astype(np.float32)


def _add_time(timings: dict[str, float] | None, stage: str, start: float) -> None:
    if timings is not None:
        timings[stage] = timings.get(stage, 0.0) + 1e3 * (time.perf_counter() - start)


def _sq_norms(x: np.ndarray) -> np.ndarray:
    return np.einsum('ij,ij->i', x, x)


def _pack(dist_sq: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Sortable uint64 key: float32 bits of a non-negative distance, then a 32-bit index."""
    bits = np.ascontiguousarray(np.maximum(dist_sq, 0), dtype=np.float32).view(np.uint32)
    return (bits.astype(np.uint64) << np.uint64(32)) | index.astype(np.uint64)


def _unpack(key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`_pack`: (squared distance float32, index int64)."""
    dist_sq = (key >> np.uint64(32)).astype(np.uint32).view(np.float32)
    return dist_sq, (key & _LOW32).astype(np.int64)


def _is_mutual(kind: str) -> bool:
    if kind not in ('nn', 'mnn'):
        raise ValueError(f'unknown matcher {kind!r}; use nn or mnn')
    return kind == 'mnn'


def _empty() -> Correspondences:
    return Correspondences(
        np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.float32)
    )

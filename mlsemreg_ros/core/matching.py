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
Group Matching, Mask Matching and ML-SemReg = GM o MM (paper Sec. 3.2-3.3).

Definitions (paper; docs/definitions.md):

* Group Matching (eq. 2-3): group G_s holds the source and target keypoints whose Local-SS
  contains label s; correspondences are the union over groups of the matcher run inside
  each group.
* Mask Matching (eq. 7-8): in a group, row i of the scene similarity S (eq. 6) keeps the
  targets j with ``S[i, j] >= max_j S[i, j] - (K - 1)`` (the top-K *levels*, ties
  included, as the reference implementation); the matcher selects among those by
  descriptor distance (masked argmin on distances, never an argmax of underflowing scores).
* ML-SemReg (eq. 9): Mask Matching inside every group, union of the results.

The engine (:func:`semantic_match`) is exact and avoids the dense |P| x |Q| x |bins| work:

1. Targets are sorted by their group pattern (Local-SS bitmask); a group touches only its
   own rows and targets (sum over groups of |P_s| |Q_s| is about 2/3 of |P| |Q| on KITTI).
2. In a group, S (eq. 6) is built per chunk of source rows as a gather-add of target bin
   rows (BMR-SS has 2-15 set bins a row), once per distinct target BMR-SS ("pattern",
   about half of the targets at 5000 keypoints); its row maxima give m_s(i).
3. A (row, group) with threshold ``T = m_s(i) - (K - 1) <= 0`` keeps every target of the
   group ("permissive": little landmark evidence, the mask cannot help); it is matched
   densely inside the group. Otherwise ("restrictive") only targets with S >= T qualify;
   they are gathered as sparse candidates (typically ~1 % of the targets) and the
   descriptor distance is read at those pairs from one GEMM per chunk, restricted to the
   targets that are a candidate of some row of the chunk (rows are ordered by BMR-SS, so
   a chunk holds neighbouring keypoints). When thin landmark evidence makes more than
   ``_DENSE_FRACTION`` of a chunk candidates, the chunk is resolved densely instead
   (same distances, same winners).
4. Per (row, group) the winner is the smallest packed key (distance bits << 32 | index);
   MNN checks the same keys in the other direction. The reported distance of each
   correspondence is recomputed directly, so it does not depend on the BLAS blocking.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
import os
import threading
import time
from typing import Any

from mlsemreg_ros.core import threads
from mlsemreg_ros.core.config import SemanticConfig
from mlsemreg_ros.core.results import Correspondences, PreparedScan
from mlsemreg_ros.core.signatures import binary_multi_ring_signature
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


@dataclass
class MatchOutcome:
    """Correspondences of ML-SemReg and how they were obtained."""

    correspondences: Correspondences
    mode: str  # 'ml-semreg' or 'gm-only'
    message: str = ''
    diagnostics: dict[str, Any] = field(default_factory=dict)


# ----------------------------------------------------------------------------------------
def ml_semreg(
    source: PreparedScan,
    target: PreparedScan,
    config: SemanticConfig,
    kind: str = 'nn',
    timings: dict[str, float] | None = None,
    class_names: tuple[str, ...] | None = None,
) -> MatchOutcome:
    """
    ML-SemReg correspondences (eq. 9) between two prepared scans.

    Landmark classes enter BMR-SS only when both scans have them. When either scan has
    fewer than ``config.min_landmarks`` such landmarks, Mask Matching is skipped and
    Group Matching runs alone (mode ``'gm-only'``, reported in the message).
    """

    def name(c: int) -> str:
        return class_names[c] if class_names is not None else str(c)

    src_counts, dst_counts = source.landmarks.counts(), target.landmarks.counts()
    shared = np.array(sorted(set(src_counts) & set(dst_counts)), dtype=np.int64)
    n_src = sum(src_counts[c] for c in shared.tolist())
    n_dst = sum(dst_counts[c] for c in shared.tolist())
    diagnostics: dict[str, Any] = {
        'landmarks_source': {name(c): n for c, n in src_counts.items()},
        'landmarks_target': {name(c): n for c, n in dst_counts.items()},
        'landmark_classes_shared': [name(c) for c in shared.tolist()],
    }
    src_groups, dst_groups = group_bitmask(source.local_ss), group_bitmask(target.local_ss)
    mutual = _is_mutual(kind)
    if len(shared) == 0 or min(n_src, n_dst) < max(config.min_landmarks, 1):
        message = (
            f'GM-only fallback: {n_src} source / {n_dst} target landmarks of shared '
            f'classes, fewer than semantic.min_landmarks={config.min_landmarks}'
        )
        corr = semantic_match(
            source.descriptors,
            target.descriptors,
            src_groups,
            dst_groups,
            None,
            None,
            config.top_k,
            mutual,
            diagnostics,
            timings=timings,
        )
        return MatchOutcome(corr, 'gm-only', message, diagnostics)
    start = time.perf_counter()
    src_bmr = binary_multi_ring_signature(
        source.keypoints, source.landmarks, shared, config.ring_count, config.ring_width
    )
    dst_bmr = binary_multi_ring_signature(
        target.keypoints, target.landmarks, shared, config.ring_count, config.ring_width
    )
    _add_time(timings, 'bmr_ss_ms', start)
    corr = semantic_match(
        source.descriptors,
        target.descriptors,
        src_groups,
        dst_groups,
        src_bmr,
        dst_bmr,
        config.top_k,
        mutual,
        diagnostics,
        timings=timings,
    )
    return MatchOutcome(corr, 'ml-semreg', '', diagnostics)


def group_matching(
    source_descriptors: np.ndarray,
    target_descriptors: np.ndarray,
    source_local_ss: np.ndarray,
    target_local_ss: np.ndarray,
    kind: str = 'nn',
) -> Correspondences:
    """Group Matching alone (eq. 3): the matcher inside every Local-SS group, united."""
    return semantic_match(
        source_descriptors,
        target_descriptors,
        group_bitmask(source_local_ss),
        group_bitmask(target_local_ss),
        None,
        None,
        1,
        _is_mutual(kind),
    )


def match_descriptors(
    source_descriptors: np.ndarray, target_descriptors: np.ndarray, kind: str = 'nn'
) -> Correspondences:
    """Plain matcher over all keypoints (the paper's baseline): NN or mutual NN."""
    src = np.ones(len(source_descriptors), dtype=np.uint64)
    dst = np.ones(len(target_descriptors), dtype=np.uint64)
    return semantic_match(
        source_descriptors, target_descriptors, src, dst, None, None, 1, _is_mutual(kind)
    )


def group_bitmask(local_ss: np.ndarray) -> np.ndarray:
    """Local-SS (M, C <= 64) bool -> (M,) uint64 bitmask of the groups a keypoint joins."""
    if local_ss.shape[1] > 64:
        raise ValueError('at most 64 classes are supported')
    weights = np.left_shift(np.uint64(1), np.arange(local_ss.shape[1], dtype=np.uint64))
    if local_ss.shape[1] == 0:
        return np.zeros(len(local_ss), dtype=np.uint64)
    return np.bitwise_or.reduce(np.where(local_ss, weights, np.uint64(0)), axis=1)


# ----------------------------------------------------------------------------------------
def semantic_match(
    source_descriptors: np.ndarray,
    target_descriptors: np.ndarray,
    source_groups: np.ndarray,
    target_groups: np.ndarray,
    source_bmr: np.ndarray | sp.spmatrix | None,
    target_bmr: np.ndarray | sp.spmatrix | None,
    top_k: int,
    mutual: bool,
    diagnostics: dict[str, Any] | None = None,
    *,
    timings: dict[str, float] | None = None,
) -> Correspondences:
    """
    Masked group matching: GM (BMR-SS None) or GM o MM (BMR-SS given), NN or MNN.

    source_descriptors (M, D), target_descriptors (M', D) float; *_groups (M,) uint64
    bitmasks of group membership; *_bmr (M, T*N) BMR-SS (bool array or sparse matrix; a
    nonzero entry is a set bit) or None. Returns the union over groups of the per-group
    matches, duplicates removed, with descriptor distances. ``timings`` (ms, accumulated)
    receives ``gm_mm_mask_ms`` (Mask Matching: S, thresholds, candidates, winners) and
    ``gm_mm_dense_ms`` (unmasked nearest neighbours of the permissive rows).
    """
    src = np.ascontiguousarray(source_descriptors, dtype=np.float32)
    dst_all = np.ascontiguousarray(target_descriptors, dtype=np.float32)
    groups_present = np.bitwise_or.reduce(
        source_groups, initial=np.uint64(0)
    ) & np.bitwise_or.reduce(target_groups, initial=np.uint64(0))
    num_groups = int(groups_present).bit_length()
    if len(src) == 0 or len(dst_all) == 0 or num_groups == 0:
        return _empty()
    # 1. targets sorted into blocks of equal group pattern; targets in no group cannot match
    order = np.argsort(target_groups, kind='stable')
    order = order[target_groups[order] != 0]
    pattern = target_groups[order]
    dst = dst_all[order]
    starts = np.flatnonzero(np.r_[True, pattern[1:] != pattern[:-1]])
    block_of_col = np.repeat(np.arange(len(starts)), np.diff(np.r_[starts, len(order)]))
    bits = np.left_shift(np.uint64(1), np.arange(num_groups, dtype=np.uint64))
    block_in_group = (pattern[starts][:, None] & bits[None, :]) != 0  # (B, G)
    col_in_group = block_in_group[block_of_col]  # (M', G)
    row_in_group = ((source_groups[:, None] & bits[None, :]) != 0) & block_in_group.any(0)
    fwd = np.full(len(src) * num_groups, NO_MATCH)
    bwd = np.full(len(dst) * num_groups, NO_MATCH) if mutual else None

    permissive = row_in_group
    if source_bmr is not None and target_bmr is not None:
        start = time.perf_counter()
        restrictive = _masked_candidates(
            src,
            dst,
            row_in_group,
            col_in_group,
            _dense_bits(source_bmr),
            _dense_bits(target_bmr)[order],
            top_k,
            fwd,
            bwd,
            diagnostics,
        )
        permissive = row_in_group & ~restrictive
        _add_time(timings, 'gm_mm_mask_ms', start)
    start = time.perf_counter()
    _dense_group_nn(src, dst, permissive, col_in_group, fwd, bwd)
    _add_time(timings, 'gm_mm_dense_ms', start)
    if diagnostics is not None:
        diagnostics['matching_groups'] = int(row_in_group.any(0).sum())
        diagnostics['permissive_row_groups'] = int(permissive.sum())
        diagnostics['row_groups'] = int(row_in_group.sum())

    # 4. winners per (row, group), mutual check, union over groups
    slots = np.flatnonzero(fwd != NO_MATCH)
    rows, group = slots // num_groups, slots % num_groups
    dist_sq, cols = _unpack(fwd[slots])
    if mutual:
        _, back_rows = _unpack(bwd[cols * num_groups + group])
        keep = back_rows == rows
        rows, cols, dist_sq = rows[keep], cols[keep], dist_sq[keep]
    _, first = np.unique(rows * len(dst) + cols, return_index=True)
    rows, cols = rows[first].astype(np.int64), order[cols[first]].astype(np.int64)
    return Correspondences(
        rows, cols, _exact_distance(source_descriptors, target_descriptors, rows, cols)
    )


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

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

Definitions (paper, DESIGN.md section 3):

* Group Matching (eq. 2-3): group G_s holds the source and target keypoints whose Local-SS
  contains label s; correspondences are the union over groups of the matcher run inside
  each group.
* Mask Matching (eq. 6-9): in a group, row i of the scene similarity S (eq. 5) keeps the
  targets j with ``S[i, j] >= max_j S[i, j] - (K - 1)`` (the top-K *levels*, ties
  included, as the reference implementation); the matcher selects among those by
  descriptor distance (masked argmin on distances, never an argmax of underflowing scores).
* ML-SemReg (eq. 10): Mask Matching inside every group, union of the results.

The engine (:func:`semantic_match`) is exact and avoids the dense |P| x |Q| x |bins| work:

1. Targets are sorted by their group pattern (Local-SS bitmask) into blocks; a block
   belongs to exactly the same groups.
2. S is built in row chunks as a sparse (BMR-SS is 2-15 bits a row) times dense uint8
   product; per-block row maxima give every row's maximum m_s(i) in every group.
3. A (row, group) with threshold ``T = m_s(i) - (K - 1) <= 0`` keeps every target of the
   group ("permissive": little landmark evidence, the mask cannot help); it is matched
   densely inside the group. Otherwise ("restrictive") only targets with S >= T qualify;
   they are gathered as sparse candidates (typically ~1 % of the targets) and the
   descriptor distance is evaluated at those pairs only.
4. Per (row, group) the winner is the smallest packed key (distance bits << 32 | index),
   scattered with ``np.minimum.at``; MNN checks the same keys in the other direction.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
import os
import time
from typing import Any

from mlsemreg_ros.core.config import SemanticConfig
from mlsemreg_ros.core.results import Correspondences, PreparedScan
from mlsemreg_ros.core.signatures import bmr_signature_sparse
import numpy as np
import scipy.sparse as sp

try:  # optional: pins BLAS to one thread while the matcher's own threads run
    from threadpoolctl import threadpool_limits
except ImportError:  # pragma: no cover
    threadpool_limits = None

NO_MATCH = np.uint64(0xFFFFFFFFFFFFFFFF)
_LOW32 = np.uint64(0xFFFFFFFF)
_DENSE_BLOCK_ELEMENTS = 2_000_000  # rows x targets per dense distance block
_CHUNK_ELEMENTS = 600_000  # rows x targets per Mask Matching chunk (cache sized)
_MAX_THREADS = 2


@dataclass
class MatchOutcome:
    """Correspondences of ML-SemReg and how they were obtained."""

    correspondences: Correspondences
    mode: str  # 'ml-semreg' or 'gm-only'
    message: str = ''
    diagnostics: dict[str, Any] = field(default_factory=dict)


# ----------------------------------------------------------------------------------------
def ml_semreg(source: PreparedScan, target: PreparedScan, config: SemanticConfig,
              kind: str = 'nn', timings: dict[str, float] | None = None,
              class_names: tuple[str, ...] | None = None) -> MatchOutcome:
    """
    ML-SemReg correspondences (eq. 10) between two prepared scans.

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
        message = (f'GM-only fallback: {n_src} source / {n_dst} target landmarks of shared '
                   f'classes, fewer than semantic.min_landmarks={config.min_landmarks}')
        corr = semantic_match(source.descriptors, target.descriptors, src_groups, dst_groups,
                              None, None, config.top_k, mutual, diagnostics)
        return MatchOutcome(corr, 'gm-only', message, diagnostics)
    start = time.perf_counter()
    src_bmr = bmr_signature_sparse(source.keypoints, source.landmarks, shared,
                                   config.ring_count, config.ring_width)
    dst_bmr = bmr_signature_sparse(target.keypoints, target.landmarks, shared,
                                   config.ring_count, config.ring_width)
    if timings is not None:
        timings['bmr_ss_ms'] = timings.get('bmr_ss_ms', 0.0) + 1e3 * (time.perf_counter() - start)
    corr = semantic_match(source.descriptors, target.descriptors, src_groups, dst_groups,
                          src_bmr, dst_bmr, config.top_k, mutual, diagnostics)
    return MatchOutcome(corr, 'ml-semreg', '', diagnostics)


def group_matching(source_descriptors: np.ndarray, target_descriptors: np.ndarray,
                   source_local_ss: np.ndarray, target_local_ss: np.ndarray,
                   kind: str = 'nn') -> Correspondences:
    """Group Matching alone (eq. 3): the matcher inside every Local-SS group, united."""
    return semantic_match(source_descriptors, target_descriptors,
                          group_bitmask(source_local_ss), group_bitmask(target_local_ss),
                          None, None, 1, _is_mutual(kind))


def match_descriptors(source_descriptors: np.ndarray, target_descriptors: np.ndarray,
                      kind: str = 'nn') -> Correspondences:
    """Plain matcher over all keypoints (the paper's baseline): NN or mutual NN."""
    src = np.ones(len(source_descriptors), dtype=np.uint64)
    dst = np.ones(len(target_descriptors), dtype=np.uint64)
    return semantic_match(source_descriptors, target_descriptors, src, dst, None, None, 1,
                          _is_mutual(kind))


def group_bitmask(local_ss: np.ndarray) -> np.ndarray:
    """Local-SS (M, C <= 64) bool -> (M,) uint64 bitmask of the groups a keypoint joins."""
    if local_ss.shape[1] > 64:
        raise ValueError('at most 64 classes are supported')
    weights = np.left_shift(np.uint64(1), np.arange(local_ss.shape[1], dtype=np.uint64))
    if local_ss.shape[1] == 0:
        return np.zeros(len(local_ss), dtype=np.uint64)
    return np.bitwise_or.reduce(np.where(local_ss, weights, np.uint64(0)), axis=1)


# ----------------------------------------------------------------------------------------
def semantic_match(source_descriptors: np.ndarray, target_descriptors: np.ndarray,
                   source_groups: np.ndarray, target_groups: np.ndarray,
                   source_bmr: sp.csr_matrix | None, target_bmr: sp.csr_matrix | None,
                   top_k: int, mutual: bool,
                   diagnostics: dict[str, Any] | None = None) -> Correspondences:
    """
    Masked group matching: GM (BMR-SS None) or GM o MM (BMR-SS given), NN or MNN.

    source_descriptors (M, D), target_descriptors (M', D) float; *_groups (M,) uint64
    bitmasks of group membership; *_bmr (M, T*N) CSR BMR-SS or None. Returns the union over
    groups of the per-group matches, duplicates removed, with descriptor distances.
    """
    src = np.ascontiguousarray(source_descriptors, dtype=np.float32)
    dst_all = np.ascontiguousarray(target_descriptors, dtype=np.float32)
    groups_present = (np.bitwise_or.reduce(source_groups, initial=np.uint64(0))
                      & np.bitwise_or.reduce(target_groups, initial=np.uint64(0)))
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
        restrictive = _masked_candidates(src, dst, source_groups, pattern, starts,
                                         block_in_group, row_in_group, source_bmr,
                                         target_bmr[order], top_k, fwd, bwd, diagnostics)
        permissive = row_in_group & ~restrictive
    _dense_group_nn(src, dst, permissive, col_in_group, fwd, bwd)
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
    return Correspondences(rows[first].astype(np.int64), order[cols[first]].astype(np.int64),
                           np.sqrt(dist_sq[first]).astype(np.float32))


def _masked_candidates(src: np.ndarray, dst: np.ndarray, source_groups: np.ndarray,
                       col_pattern: np.ndarray, starts: np.ndarray,
                       block_in_group: np.ndarray, row_in_group: np.ndarray,
                       source_bmr: sp.csr_matrix, target_bmr: sp.csr_matrix, top_k: int,
                       fwd: np.ndarray, bwd: np.ndarray | None,
                       diagnostics: dict[str, Any] | None) -> np.ndarray:
    """
    Run steps 2-3 for restrictive (row, group) pairs; return the (M, G) restrictive mask.

    Row chunks are independent (each writes only its own rows of ``fwd``), so they run on
    a small thread pool; NumPy and BLAS release the GIL in these kernels.
    """
    num_rows, num_groups = row_in_group.shape
    # S <= number of source landmarks; uint8 holds it (255 = "no threshold") below 255.
    s_type = np.uint8 if source_bmr.getnnz(axis=1).max(initial=0) < 255 else np.uint16
    context = _MaskContext(
        src=src, dst=dst, src_sq=_sq_norms(src), dst_sq=_sq_norms(dst),
        source_groups=source_groups, col_pattern=col_pattern,
        block_sizes=np.diff(np.r_[starts, len(dst)]), starts=starts,
        blocks_of_group=[np.flatnonzero(block_in_group[:, g]) for g in range(num_groups)],
        row_in_group=row_in_group, src_bmr=source_bmr.astype(s_type).tocsr(),
        dst_bmr_t=np.ascontiguousarray(target_bmr.toarray().T.astype(s_type)),
        top_k=top_k, none=int(np.iinfo(s_type).max), s_type=s_type,
        threshold=np.zeros((num_rows, num_groups), dtype=np.int32), fwd=fwd,
        mutual=bwd is not None)
    chunk = max(1, _CHUNK_ELEMENTS // max(len(dst), 1))
    bounds = [(lo, min(num_rows, lo + chunk)) for lo in range(0, num_rows, chunk)]
    # The chunk GEMMs are small: multithreaded BLAS on them (and inside worker threads) was
    # measured 3x slower, so BLAS runs single-threaded here and the chunks use the cores.
    with _single_threaded_blas(), ThreadPoolExecutor(_workers(len(bounds))) as pool:
        results = list(pool.map(lambda b: _masked_chunk(context, *b), bounds))
    if bwd is not None:
        slots = np.concatenate([r[0] for r in results])
        np.minimum.at(bwd, slots, np.concatenate([r[1] for r in results]))
    if diagnostics is not None:
        diagnostics['mask_candidates'] = int(sum(r[2] for r in results))
    return context.threshold >= 1


@dataclass
class _MaskContext:
    """Read-only inputs (and disjoint outputs) shared by the row chunks of Mask Matching."""

    src: np.ndarray
    dst: np.ndarray
    src_sq: np.ndarray
    dst_sq: np.ndarray
    source_groups: np.ndarray
    col_pattern: np.ndarray
    block_sizes: np.ndarray
    starts: np.ndarray
    blocks_of_group: list[np.ndarray]
    row_in_group: np.ndarray
    src_bmr: sp.csr_matrix
    dst_bmr_t: np.ndarray
    top_k: int
    none: int
    s_type: type
    threshold: np.ndarray
    fwd: np.ndarray
    mutual: bool


def _masked_chunk(ctx: _MaskContext, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Mask Matching of source rows [lo, hi): thresholds, candidates, per-group winners."""
    num_groups = ctx.threshold.shape[1]
    similarity = ctx.src_bmr[lo:hi] @ ctx.dst_bmr_t  # (R, M') scene similarity, eq. 5
    block_max = np.maximum.reduceat(similarity, ctx.starts, axis=1)  # (R, B)
    loosest = np.full(block_max.shape, ctx.none, dtype=ctx.s_type)  # (R, B)
    threshold = ctx.threshold[lo:hi]
    for g, blocks in enumerate(ctx.blocks_of_group):  # groups, not points
        if len(blocks) == 0:
            continue
        # T = m_s(i) - (K - 1); a (row, group) is restrictive iff T >= 1
        thr = block_max[:, blocks].max(axis=1).astype(np.int32) - (ctx.top_k - 1)
        thr[~ctx.row_in_group[lo:hi, g] | (thr < 1)] = 0
        threshold[:, g] = thr
        thr_or_none = np.where(thr >= 1, thr, ctx.none).astype(ctx.s_type)
        loosest[:, blocks] = np.minimum(loosest[:, blocks], thr_or_none[:, None])
    # candidates: S >= the loosest restrictive threshold of the column's block
    flat = np.flatnonzero(similarity >= np.repeat(loosest, ctx.block_sizes, axis=1))
    rows, cols = np.divmod(flat, similarity.shape[1])
    sim = similarity.reshape(-1)[flat].astype(np.int32)
    # ||a - b||^2 = ||a||^2 + ||b||^2 - 2 a.b: one GEMM for the chunk, read at the candidates
    dist_sq = (ctx.src[lo:hi] @ ctx.dst.T).reshape(-1)[flat]
    dist_sq *= -2.0
    dist_sq += ctx.src_sq[lo + rows] + ctx.dst_sq[cols]
    np.maximum(dist_sq, 0.0, out=dist_sq)
    # expand each candidate into the groups it shares (1-3 typically) by peeling set bits
    common = ctx.source_groups[lo + rows] & ctx.col_pattern[cols]
    flat_threshold = threshold.reshape(-1)
    keep_idx, keep_group = [], []
    idx = np.arange(len(rows))
    while len(idx):
        bits = common[idx]
        low = bits & (~bits + np.uint64(1))  # lowest set bit
        group = np.log2(low.astype(np.float64)).astype(np.int64)
        thr = flat_threshold[rows[idx] * num_groups + group]
        ok = (thr >= 1) & (sim[idx] >= thr)
        keep_idx.append(idx[ok])
        keep_group.append(group[ok])
        bits ^= low
        common[idx] = bits
        idx = idx[bits != 0]
    sel = np.concatenate(keep_idx) if keep_idx else np.zeros(0, dtype=np.int64)
    group = np.concatenate(keep_group) if keep_group else np.zeros(0, dtype=np.int64)
    local = np.full((hi - lo) * num_groups, NO_MATCH)
    np.minimum.at(local, rows[sel] * num_groups + group, _pack(dist_sq[sel], cols[sel]))
    ctx.fwd[lo * num_groups:hi * num_groups] = local
    if not ctx.mutual:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.uint64), len(rows)
    return cols[sel] * num_groups + group, _pack(dist_sq[sel], lo + rows[sel]), len(rows)


def _workers(tasks: int) -> int:
    if threadpool_limits is None:
        return 1
    return max(1, min(tasks, os.cpu_count() or 1, _MAX_THREADS))


def _single_threaded_blas() -> AbstractContextManager:
    if threadpool_limits is not None:
        return threadpool_limits(limits=1, user_api='blas')
    return nullcontext()


def _dense_group_nn(src: np.ndarray, dst: np.ndarray, row_groups: np.ndarray,
                    col_in_group: np.ndarray, fwd: np.ndarray, bwd: np.ndarray | None) -> None:
    """Unmasked nearest neighbours inside every group for the (row, group) pairs given."""
    num_groups = row_groups.shape[1]
    src_sq, dst_sq = _sq_norms(src), _sq_norms(dst)
    for g in range(num_groups):  # groups, not points
        rows = np.flatnonzero(row_groups[:, g])
        cols = np.flatnonzero(col_in_group[:, g])
        if len(rows) == 0 or len(cols) == 0:
            continue
        targets, targets_sq = dst[cols], dst_sq[cols]
        step = max(1, _DENSE_BLOCK_ELEMENTS // len(cols))
        for lo in range(0, len(rows), step):
            part_rows = rows[lo:lo + step]
            inner = src[part_rows] @ targets.T
            # argmin_j ||a - b_j||^2 = argmin_j (||b_j||^2 - 2 a.b_j): ||a||^2 only for winners
            score = targets_sq[None, :] - 2.0 * inner
            best = score.argmin(axis=1)
            row_dist = score[np.arange(len(part_rows)), best] + src_sq[part_rows]
            fwd[part_rows * num_groups + g] = _pack(row_dist, cols[best])
            if bwd is not None:
                score = src_sq[part_rows, None] - 2.0 * inner
                best_row = score.argmin(axis=0)
                col_dist = score[best_row, np.arange(len(cols))] + targets_sq
                slot = cols * num_groups + g
                bwd[slot] = np.minimum(bwd[slot], _pack(col_dist, part_rows[best_row]))


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
    return Correspondences(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64),
                           np.zeros(0, dtype=np.float32))

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
   ``_DENSE_FRACTION`` of a chunk candidates, the chunk is resolved densely instead (same
   distances, same winners). Steps 2-4 are in ``core/matching/mask_search.py``.
4. Per (row, group) the winner is the smallest packed key (distance bits << 32 | index);
   MNN checks the same keys in the other direction. The reported distance of each
   correspondence is recomputed directly, so it does not depend on the BLAS blocking.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import time
from typing import Any

from mlsemreg_ros.core.matching.config import SemanticConfig
from mlsemreg_ros.core.matching.mask_search import (
    _add_time,
    _dense_bits,
    _dense_group_nn,
    _empty,
    _exact_distance,
    _is_mutual,
    _masked_candidates,
    _unpack,
    NO_MATCH,
)
from mlsemreg_ros.core.matching.signatures import binary_multi_ring_signature
from mlsemreg_ros.core.results import Correspondences, PreparedScan
import numpy as np
import scipy.sparse as sp


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


def _one_pattern(source_groups: np.ndarray, target_groups: np.ndarray) -> bool:
    """Whether every source and target keypoint joins exactly the same (nonempty) groups."""
    if len(source_groups) == 0 or len(target_groups) == 0:
        return False
    first = source_groups[0]
    return bool(first != 0 and np.all(source_groups == first) and np.all(target_groups == first))


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
    if source_bmr is None and _one_pattern(source_groups, target_groups):
        # every keypoint in the same groups (an unlabeled scan: every group): each group
        # matches alike, so one group gives the same union (~40 times faster)
        source_groups = np.ones(len(source_groups), dtype=np.uint64)
        target_groups = np.ones(len(target_groups), dtype=np.uint64)
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

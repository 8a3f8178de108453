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
"""Group Matching, Mask Matching and ML-SemReg: known answers and agreement with a reference."""

from mlsemreg_ros.core import threads as thread_settings
from mlsemreg_ros.core.matching import mask_search
from mlsemreg_ros.core.matching.matching import (
    group_bitmask,
    group_matching,
    match_descriptors,
    semantic_match,
)
import numpy as np
import pytest
from reference_matching import reference_match
import scipy.sparse as sp
from scipy.spatial import cKDTree


def _pairs(corr) -> set[tuple[int, int]]:
    return set(zip(corr.source.tolist(), corr.target.tolist(), strict=True))


def test_top_k_levels_keep_ties_and_select_by_descriptor_distance():
    # one group; row 0 similarities [5, 5, 4, 3, 1] -> K=2 keeps targets 0, 1, 2 (levels 5, 4)
    src_desc = np.array([[0.0, 0.0]])
    dst_desc = np.array([[3.0, 0], [2.0, 0], [1.0, 0], [0.1, 0], [0.0, 0]])
    src_bmr = np.zeros((1, 5), bool)
    src_bmr[0, :] = True
    dst_bmr = np.zeros((5, 5), bool)
    for j, level in enumerate([5, 5, 4, 3, 1]):
        dst_bmr[j, :level] = True
    groups_src, groups_dst = np.ones(1, np.uint64), np.ones(5, np.uint64)
    args = (
        src_desc,
        dst_desc,
        groups_src,
        groups_dst,
        sp.csr_matrix(src_bmr),
        sp.csr_matrix(dst_bmr),
    )
    assert _pairs(semantic_match(*args, top_k=2, mutual=False)) == {(0, 2)}
    assert _pairs(semantic_match(*args, top_k=1, mutual=False)) == {(0, 1)}  # tie 5, 5
    assert _pairs(semantic_match(*args, top_k=5, mutual=False)) == {(0, 4)}  # all levels


def test_group_matching_never_matches_across_groups_and_matches_in_every_group():
    src_desc = np.array([[0.0], [10.0]])
    dst_desc = np.array([[0.2], [9.0], [0.1]])
    src_ss = np.array([[1, 0], [1, 1]], bool)  # row 1 is in both groups
    dst_ss = np.array([[0, 1], [1, 0], [0, 1]], bool)
    pairs = _pairs(group_matching(src_desc, dst_desc, src_ss, dst_ss))
    # group 0 holds targets {1}; group 1 holds targets {0, 2}
    assert pairs == {(0, 1), (1, 1), (1, 0)}


def test_plain_nn_equals_kdtree_and_mnn_is_mutual():
    rng = np.random.default_rng(0)
    src, dst = rng.normal(size=(300, 8)), rng.normal(size=(250, 8))
    nn = match_descriptors(src, dst, 'nn')
    np.testing.assert_array_equal(nn.target, cKDTree(dst).query(src)[1])
    np.testing.assert_allclose(nn.distance, cKDTree(dst).query(src)[0], rtol=1e-4)
    mnn = match_descriptors(src, dst, 'mnn')
    back = cKDTree(src).query(dst)[1]
    assert all(back[j] == i for i, j in _pairs(mnn))
    assert len(mnn) == sum(back[nn.target[i]] == i for i in range(300))


@pytest.mark.parametrize('seed', range(6))
@pytest.mark.parametrize('mutual', [False, True])
@pytest.mark.parametrize('top_k', [1, 2, 3])
def test_engine_agrees_with_dense_reference(seed, mutual, top_k):
    rng = np.random.default_rng(seed)
    m, n, classes, bins = 120, 140, 6, 40
    src_desc, dst_desc = rng.normal(size=(m, 5)), rng.normal(size=(n, 5))
    src_ss = rng.random((m, classes)) < 0.3
    dst_ss = rng.random((n, classes)) < 0.3
    src_bmr = rng.random((m, bins)) < rng.uniform(0.02, 0.3)
    dst_bmr = rng.random((n, bins)) < rng.uniform(0.02, 0.3)
    fast = semantic_match(
        src_desc,
        dst_desc,
        group_bitmask(src_ss),
        group_bitmask(dst_ss),
        sp.csr_matrix(src_bmr),
        sp.csr_matrix(dst_bmr),
        top_k,
        mutual,
    )
    expected = reference_match(src_desc, dst_desc, src_ss, dst_ss, src_bmr, dst_bmr, top_k, mutual)
    assert _pairs(fast) == expected
    gm = semantic_match(
        src_desc, dst_desc, group_bitmask(src_ss), group_bitmask(dst_ss), None, None, top_k, mutual
    )
    assert _pairs(gm) == reference_match(src_desc, dst_desc, src_ss, dst_ss, None, None, 1, mutual)


def test_duplicates_across_groups_are_removed_and_distances_reported():
    src_desc, dst_desc = np.array([[0.0, 0.0]]), np.array([[3.0, 4.0]])
    both = np.array([[1, 1]], bool)
    corr = group_matching(src_desc, dst_desc, both, both)
    assert _pairs(corr) == {(0, 0)}
    np.testing.assert_allclose(corr.distance, [5.0])


def test_empty_inputs_give_no_correspondence():
    empty = match_descriptors(np.zeros((0, 4)), np.ones((3, 4)))
    assert len(empty) == 0
    no_group = group_matching(
        np.ones((2, 3)), np.ones((2, 3)), np.zeros((2, 4), bool), np.ones((2, 4), bool)
    )
    assert len(no_group) == 0


def test_rows_without_any_mask_candidate_do_not_break_matching():
    # BMR-SS given but no shared bin at all: every row is permissive, no candidate anywhere
    src_desc, dst_desc = np.array([[0.0], [1.0]]), np.array([[0.9], [0.1]])
    src_bmr = sp.csr_matrix(np.array([[1, 0, 0, 0], [1, 0, 0, 0]], bool))
    dst_bmr = sp.csr_matrix(np.array([[0, 0, 1, 0], [0, 0, 0, 1]], bool))
    ones_src, ones_dst = np.ones(2, np.uint64), np.ones(2, np.uint64)
    corr = semantic_match(src_desc, dst_desc, ones_src, ones_dst, src_bmr, dst_bmr, 1, False)
    assert _pairs(corr) == {(0, 1), (1, 0)}
    # restrictive rows whose candidates all fall outside the row's groups
    corr = semantic_match(
        src_desc,
        dst_desc,
        np.array([1, 1], np.uint64),
        np.array([2, 2], np.uint64),
        src_bmr,
        src_bmr.copy(),
        1,
        True,
    )
    assert len(corr) == 0


def _clustered_case(
    seed: int, m: int = 300, n: int = 320, classes: int = 5, bins: int = 60, patterns: int = 12
):
    """Build inputs where many keypoints share a BMR-SS pattern (as neighbours do)."""
    rng = np.random.default_rng(seed)
    src_desc, dst_desc = rng.normal(size=(m, 6)), rng.normal(size=(n, 6))
    src_ss = rng.random((m, classes)) < 0.35
    dst_ss = rng.random((n, classes)) < 0.35
    table = rng.random((patterns, bins)) < 0.15
    src_bmr = table[rng.integers(0, patterns, m)] | (rng.random((m, bins)) < 0.01)
    dst_bmr = table[rng.integers(0, patterns, n)]
    return src_desc, dst_desc, src_ss, dst_ss, src_bmr, dst_bmr


@pytest.mark.parametrize('seed', range(4))
@pytest.mark.parametrize('mutual', [False, True])
def test_engine_agrees_with_reference_on_repeated_patterns_and_small_chunks(
    seed, mutual, monkeypatch
):
    src_desc, dst_desc, src_ss, dst_ss, src_bmr, dst_bmr = _clustered_case(seed)
    expected = reference_match(src_desc, dst_desc, src_ss, dst_ss, src_bmr, dst_bmr, 2, mutual)
    args = (src_desc, dst_desc, group_bitmask(src_ss), group_bitmask(dst_ss))
    results = []
    for chunk, threads in [(600_000, 2), (97, 2), (97, 1), (5, 2)]:  # 1 .. many row chunks
        monkeypatch.setattr(mask_search, '_CHUNK_ELEMENTS', chunk)
        monkeypatch.setattr(thread_settings, '_requested', threads)
        corr = semantic_match(*args, src_bmr, dst_bmr, 2, mutual)
        assert _pairs(corr) == expected
        results.append(corr)
    for corr in results[1:]:  # identical output, distances included, for any chunking
        np.testing.assert_array_equal(corr.source, results[0].source)
        np.testing.assert_array_equal(corr.target, results[0].target)
        np.testing.assert_array_equal(corr.distance, results[0].distance)


def _match_args(case: tuple, mutual: bool) -> tuple:
    """``semantic_match``'s arguments for a :func:`_clustered_case` (top-2 levels)."""
    src_desc, dst_desc, src_ss, dst_ss, src_bmr, dst_bmr = case
    return (
        src_desc, dst_desc, group_bitmask(src_ss), group_bitmask(dst_ss), src_bmr, dst_bmr, 2,
        mutual,
    )  # fmt: skip


def test_dense_and_sparse_bmr_inputs_agree_and_explicit_zeros_are_not_bits():
    src_desc, dst_desc, src_ss, dst_ss, src_bmr, dst_bmr = _clustered_case(7)
    args = (src_desc, dst_desc, group_bitmask(src_ss), group_bitmask(dst_ss))
    dense = _pairs(semantic_match(*args, src_bmr, dst_bmr, 2, False))
    sparse_src = sp.csr_matrix(src_bmr.astype(np.uint8))
    sparse_dst = sp.csr_matrix(dst_bmr.astype(np.uint8))
    assert _pairs(semantic_match(*args, sparse_src, sparse_dst, 2, False)) == dense
    padded = sp.csr_matrix(np.where(dst_bmr, 1, 0).astype(np.uint8))
    padded = sp.csr_matrix(
        (
            np.r_[padded.data, 0],
            np.r_[padded.indices, 0],
            np.r_[padded.indptr[:-1], padded.indptr[-1] + 1],
        ),
        shape=padded.shape,
    )  # explicit zero at (last row, bin 0)
    if not dst_bmr[-1, 0]:
        assert padded.nnz == dst_bmr.sum() + 1
    assert _pairs(semantic_match(*args, sparse_src, padded, 2, False)) == dense


def test_reported_distance_is_the_exact_descriptor_distance():
    rng = np.random.default_rng(4)
    src_desc = rng.uniform(0, 300, (200, 33))  # FPFH-like magnitudes: GEMM form cancels
    dst_desc = src_desc[rng.permutation(200)] + rng.normal(0, 0.01, (200, 33))
    ss = np.ones((200, 1), bool)
    corr = group_matching(src_desc, dst_desc, ss, ss)
    exact = np.linalg.norm(src_desc[corr.source] - dst_desc[corr.target], axis=1)
    np.testing.assert_allclose(corr.distance, exact, rtol=1e-6)
    assert corr.distance.dtype == np.float32


def test_target_patterns_and_padded_bins_known_answer():
    bmr = np.zeros((5, 70), bool)
    bmr[0, [1, 65]] = bmr[2, [1, 65]] = True  # same pattern across the 64-bit word border
    bmr[1, [1]] = True
    bmr[4, [69]] = True  # row 3 empty
    pattern_of, table = mask_search._target_patterns(bmr, np.uint8)
    assert pattern_of[0] == pattern_of[2] and len(set(pattern_of.tolist())) == 4
    assert table.shape == (71, 4) and not table[-1].any()
    np.testing.assert_array_equal(table[:-1, pattern_of].T.astype(bool), bmr)
    bits, width = mask_search._padded_bins(bmr)
    assert width.tolist() == [2, 1, 2, 0, 1]
    assert bits.tolist() == [[1, 65], [1, 70], [1, 65], [70, 70], [69, 70]]


def test_bmr_without_bins_falls_back_to_group_matching():
    src_desc, dst_desc, src_ss, dst_ss, _, _ = _clustered_case(2)
    args = (src_desc, dst_desc, group_bitmask(src_ss), group_bitmask(dst_ss))
    empty_src, empty_dst = np.zeros((len(src_desc), 0), bool), np.zeros((len(dst_desc), 0), bool)
    assert _pairs(semantic_match(*args, empty_src, empty_dst, 2, False)) == _pairs(
        semantic_match(*args, None, None, 2, False)
    )


def test_matcher_reports_sub_stage_timings():
    timings: dict[str, float] = {}
    semantic_match(*_match_args(_clustered_case(3), False), timings=timings)
    assert set(timings) == {'gm_mm_mask_ms', 'gm_mm_dense_ms'}
    assert all(v >= 0 for v in timings.values())


@pytest.mark.parametrize('seed', range(3))
@pytest.mark.parametrize('mutual', [False, True])
def test_dense_and_sparse_candidate_paths_agree_with_reference(seed, mutual, monkeypatch):
    # few landmarks -> low S maxima -> many candidates: the case the dense path is for
    case = _clustered_case(seed, bins=30, patterns=4)
    expected = reference_match(*case, 2, mutual)
    args = _match_args(case, mutual)
    outputs = []
    for fraction in (0.0, np.inf):  # every chunk dense / every chunk sparse
        monkeypatch.setattr(mask_search, '_DENSE_FRACTION', fraction)
        diagnostics: dict = {}
        corr = semantic_match(*args, diagnostics)
        assert _pairs(corr) == expected
        outputs.append((corr, diagnostics['mask_candidates']))
    np.testing.assert_array_equal(outputs[0][0].distance, outputs[1][0].distance)
    assert outputs[0][1] == outputs[1][1] > 0  # same candidate count either way


@pytest.mark.filterwarnings('ignore:invalid value:RuntimeWarning')  # NaN on purpose
@pytest.mark.parametrize('mutual', [False, True])
def test_non_finite_descriptors_give_the_same_winners_on_both_candidate_paths(mutual, monkeypatch):
    case = _clustered_case(5, patterns=4)
    src_desc, dst_desc = case[:2]
    dst_desc[[3, 40]] = np.nan  # NaN and inf must sort the same way on both paths
    src_desc[7] = np.inf
    args = _match_args(case, mutual)
    results = []
    for fraction in (0.0, np.inf):
        monkeypatch.setattr(mask_search, '_DENSE_FRACTION', fraction)
        results.append(_pairs(semantic_match(*args)))
    assert results[0] == results[1] and len(results[0]) > 0


def _match_in_child(seed: int) -> set[tuple[int, int]]:
    return _pairs(semantic_match(*_match_args(_clustered_case(seed), False)))


@pytest.mark.filterwarnings('ignore:This process:DeprecationWarning')  # Python >= 3.12
def test_matcher_thread_pool_survives_fork():
    multiprocessing = pytest.importorskip('multiprocessing')
    expected = _match_in_child(1)  # the parent's pool now exists
    with multiprocessing.get_context('fork').Pool(1) as pool:
        assert pool.apply_async(_match_in_child, (1,)).get(timeout=120) == expected

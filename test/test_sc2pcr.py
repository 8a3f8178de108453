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


"""SC2-PCR stage by stage against dense reference formulas, end to end, and the baselines."""

from __future__ import annotations

from dev_pairs import dev_pair_files
from mlsemreg_ros.core import poses
from mlsemreg_ros.core.config import EstimatorConfig
from mlsemreg_ros.core.estimation import sc2pcr as sc2
from mlsemreg_ros.core.estimation import second_order
from mlsemreg_ros.core.estimation.estimation import estimate
from mlsemreg_ros.core.rigid import apply_transform
import numpy as np
import pytest
from scipy.spatial.transform import Rotation


def _problem(
    seed: int,
    count: int = 1000,
    outlier_ratio: float = 0.9,
    noise: float = 0.05,
    box: float = 80.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Correspondences under a random rigid motion; outliers uniform in the box."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    truth = np.eye(4)
    truth[:3, :3] = Rotation.from_rotvec(
        rng.uniform(0.0, np.pi) * axis / np.linalg.norm(axis)
    ).as_matrix()
    direction = rng.normal(size=3)
    truth[:3, 3] = rng.uniform(0.0, 30.0) * direction / np.linalg.norm(direction)
    src = rng.uniform(-box / 2, box / 2, (count, 3))
    dst = apply_transform(truth, src) + rng.normal(0.0, noise, (count, 3))
    outliers = rng.permutation(count)[: round(count * outlier_ratio)]
    dst[outliers] = rng.uniform(-box / 2, box / 2, (outliers.size, 3)) + truth[:3, 3]
    inliers = np.ones(count, dtype=bool)
    inliers[outliers] = False
    return src, dst, truth, inliers


def _errors(estimate_: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Rotation error (deg) and translation error (m)."""
    cos = (np.trace(truth[:3, :3].T @ estimate_[:3, :3]) - 1.0) / 2.0
    return (
        float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))),
        float(np.linalg.norm(estimate_[:3, 3] - truth[:3, 3])),
    )


def _dense_cross(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    return np.abs(
        np.linalg.norm(src[:, None] - src[None], axis=-1)
        - np.linalg.norm(dst[:, None] - dst[None], axis=-1)
    )


# -- stages against dense formulas ---------------------------------------------------------


@pytest.mark.parametrize(('scale', 'threshold'), [(40.0, 0.6), (3.0, 0.05), (500.0, 0.02)])
def test_compatibility_matches_dense_formula(scale: float, threshold: float) -> None:
    # the last case has a large extent for its threshold and takes the float64 path
    src, dst, _, _ = _problem(7, count=600, outlier_ratio=0.5, noise=threshold / 10, box=2 * scale)
    src[:20] = src[20:40] + 1e-3  # near-duplicates: short distances are computed exactly
    cross = _dense_cross(src, dst)
    expected = np.where(cross < threshold, 1.0 - (cross / threshold) ** 2, 0.0)
    matrix = sc2.compatibility_matrix(src, dst, threshold)
    dense = matrix.toarray()
    assert matrix.has_sorted_indices
    boundary = np.abs(cross - threshold) < 1e-5  # rounding may flip entries on the threshold
    assert np.array_equal((dense > 0)[~boundary], (cross < threshold)[~boundary])
    np.testing.assert_allclose(dense[~boundary], expected[~boundary], atol=2e-3)
    np.testing.assert_array_equal(np.diag(dense), 1.0)
    np.testing.assert_array_equal(dense, dense.T)


@pytest.mark.parametrize('enumeration_cost', [1e-9, 4.0, 1e9])
def test_second_order_matches_dense_formula(
    monkeypatch: pytest.MonkeyPatch, enumeration_cost: float
) -> None:
    # all-enumerated, the default split, all bit sets: the same SC2 (eq. 4)
    monkeypatch.setattr(second_order, '_ENUMERATION_COST', enumeration_cost)
    monkeypatch.setattr(second_order, '_BIT_CHUNK_WORDS', 64)  # many chunks
    monkeypatch.setattr(second_order, '_LIGHT_TABLE_ENTRIES', 5000)
    src, dst, _, _ = _problem(8, count=700, outlier_ratio=0.7)
    threshold = 0.6
    cross = _dense_cross(src, dst)
    hard = (cross < threshold).astype(float)
    tight = (cross < threshold / 2).astype(float)
    seeds = np.random.default_rng(0).choice(700, 90, replace=False)
    expected = hard[seeds] * (tight[seeds] @ tight)
    row, col, value = second_order.second_order_compatibility(
        sc2.compatibility_matrix(src, dst, threshold), seeds
    )
    result = np.zeros_like(expected)
    result[row, col] = value
    np.testing.assert_array_equal(result, expected)
    assert np.all(hard[seeds[row], col] == 1)


def test_seeds_are_local_maxima_in_score_order() -> None:
    rng = np.random.default_rng(9)
    src = rng.uniform(0.0, 3.0, (400, 3))
    src[200:] = src[:200]  # every point twice: one of each duplicate pair is suppressed
    scores = rng.random(400)
    radius = 0.4
    seeds = sc2.pick_seeds(src, scores, radius, 1000)
    near = np.linalg.norm(src[:, None] - src[None], axis=-1) < radius
    is_max = ~np.any(near & (scores[None, :] > scores[:, None]), axis=1)
    np.testing.assert_array_equal(np.sort(seeds), np.flatnonzero(is_max))
    assert np.all(np.diff(scores[seeds]) <= 0)
    np.testing.assert_array_equal(sc2.pick_seeds(src, scores, radius, 5), seeds[:5])
    assert sc2.pick_seeds(src, scores, 0.0, 1000).size == 400  # radius 0: no suppression


def test_consensus_sets_put_the_seed_first_and_rank_by_sc2() -> None:
    src, dst, _, _ = _problem(10, count=500, outlier_ratio=0.6)
    matrix = sc2.compatibility_matrix(src, dst, 0.6)
    seeds = np.array([3, 50, 400])
    consensus, valid = second_order.seed_consensus_sets(matrix, seeds, 30)
    row, col, value = second_order.second_order_compatibility(matrix, seeds)
    table = np.zeros((3, 500))
    table[row, col] = value
    np.testing.assert_array_equal(consensus[:, 0], seeds)
    for r in range(3):
        chosen = consensus[r, 1:][valid[r, 1:]]
        scores = table[r, chosen]
        assert np.all(scores > 0) and np.all(np.diff(scores) <= 0)
        others = np.setdiff1d(np.flatnonzero(table[r] > 0), np.append(chosen, seeds[r]))
        if others.size:  # nothing left out beats what was chosen
            assert table[r, others].max() <= scores.min()


def test_seed_budget_keeps_the_best_seeds_of_dense_input() -> None:
    # 60 % inliers: dense compatibility, expensive SC2 rows
    src, dst, truth, _ = _problem(15, count=1500, outlier_ratio=0.4)
    matrix = sc2.compatibility_matrix(src, dst, 0.6)
    tight = second_order.tight_compatibility(matrix)
    scores, _ = sc2.leading_eigenvector(matrix, 10)
    seeds = sc2.pick_seeds(src, scores, 0.1, 300)
    cost = second_order.second_order_cost(matrix, tight, seeds)
    assert cost.shape == seeds.shape and np.all(np.diff(cost) >= 0)
    np.testing.assert_array_equal(second_order.budget_seeds(matrix, tight, seeds, np.inf), seeds)
    kept = second_order.budget_seeds(matrix, tight, seeds, cost[99])
    np.testing.assert_array_equal(kept, seeds[:100])  # a prefix: the best scores
    np.testing.assert_array_equal(
        second_order.budget_seeds(matrix, tight, seeds, 0.0), seeds[: second_order._MIN_SEEDS]
    )
    # end to end with a small budget (estimator.second_order_budget): fewer seeds, same result
    result = sc2.sc2pcr(
        src,
        dst,
        EstimatorConfig(second_order_budget=float(cost[99]) / 1e6, seed_ratio=0.2, graph_size=0),
    )
    assert result.diagnostics['n_seeds'] < result.diagnostics['n_seeds_nms']
    assert _errors(result.transform, truth)[0] < 0.5
    unbudgeted = sc2.sc2pcr(src, dst, EstimatorConfig(second_order_budget=0.0, graph_size=0))
    assert unbudgeted.diagnostics['n_seeds'] == unbudgeted.diagnostics['n_seeds_nms']


def _plain_seed_hypothesis(
    src: np.ndarray,
    dst: np.ndarray,
    consensus: np.ndarray,
    valid: np.ndarray,
    k2: int,
    threshold: float,
) -> np.ndarray:
    """
    Follow SC2-PCR's per-seed steps one seed at a time, with dense NumPy.

    Second-stage sampling by the local SC2 row of the seed, local SC with zero
    diagonal, its leading eigenvector (dense ``eigh``) as SVD weights.
    """
    members = consensus[valid]
    cross = _dense_cross(src[members], dst[members])
    hard = (cross < threshold).astype(float)
    score = hard[0] @ hard  # the seed is the first member
    fine = members[np.argsort(-score, kind='stable')[:k2]]
    cross = _dense_cross(src[fine], dst[fine])
    local = np.clip(1.0 - (cross / threshold) ** 2, 0.0, None)
    np.fill_diagonal(local, 0.0)
    _, vectors = np.linalg.eigh(local)
    weights = np.abs(vectors[:, -1])
    weights /= weights.sum()
    centre_src, centre_dst = weights @ src[fine], weights @ dst[fine]
    cov = (src[fine] - centre_src).T @ np.diag(weights) @ (dst[fine] - centre_dst)
    u, _, vt = np.linalg.svd(cov)
    fix = np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    rotation = vt.T @ fix @ u.T
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = centre_dst - rotation @ centre_src
    return transform


def test_seed_hypotheses_match_a_plain_per_seed_implementation() -> None:
    src, dst, _, _ = _problem(14, count=400, outlier_ratio=0.6, noise=0.1)
    matrix = sc2.compatibility_matrix(src, dst, 0.6)
    scores, _ = sc2.leading_eigenvector(matrix, 10)
    seeds = sc2.pick_seeds(src, scores, 0.1, 80)
    consensus, valid = second_order.seed_consensus_sets(matrix, seeds, 30)
    hypotheses = sc2.seed_hypotheses(src, dst, consensus, valid, 20, 0.6, iterations=200)
    assert hypotheses.shape == (seeds.size, 4, 4)
    checked = 0
    for s in range(seeds.size):
        if valid[s].sum() < 20:  # short sets: padding, compared in the end-to-end tests
            continue
        expected = _plain_seed_hypothesis(src, dst, consensus[s], valid[s], 20, 0.6)
        np.testing.assert_allclose(hypotheses[s], expected, atol=2e-3)
        checked += 1
    assert checked >= 20


@pytest.mark.parametrize(('sets', 'size'), [(1, 1), (1, 30), (37, 30), (200, 7)])
def test_cross_lengths_match_the_dense_formula_per_set(sets: int, size: int) -> None:
    rng = np.random.default_rng(sets * 100 + size)
    src = rng.uniform(-40.0, 40.0, (sets, size, 3)).astype(np.float32)
    dst = rng.uniform(-40.0, 40.0, (sets, size, 3)).astype(np.float32)
    cross = sc2._cross_lengths(src, dst)
    assert cross.shape == (sets, size, size) and cross.flags.c_contiguous
    expected = np.stack(
        [_dense_cross(src[s].astype(float), dst[s].astype(float)) for s in range(sets)]
    )
    np.testing.assert_allclose(cross, expected, atol=1e-4)
    np.testing.assert_array_equal(cross, cross.transpose(0, 2, 1))  # exactly symmetric
    assert np.all(np.diagonal(cross, axis1=1, axis2=2) == 0.0)


def test_leading_eigenvector_of_a_known_matrix() -> None:
    block = np.ones((5, 5))
    matrix = np.zeros((8, 8))
    matrix[:5, :5] = block
    matrix[5:, 5:] = np.eye(3)
    from scipy import sparse

    vector, eigenvalue = sc2.leading_eigenvector(sparse.csr_matrix(matrix, dtype=np.float32), 50)
    assert eigenvalue == pytest.approx(5.0, rel=1e-5)
    np.testing.assert_allclose(vector[:5], 1 / np.sqrt(5), atol=1e-5)
    assert np.abs(vector[5:]).max() < 1e-4


# -- end to end -----------------------------------------------------------------------------


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_sc2pcr_recovers_transform_with_90_percent_outliers(seed: int) -> None:
    src, dst, truth, inliers = _problem(seed)
    result = estimate(src, dst, EstimatorConfig())
    rotation_error, translation_error = _errors(result.transform, truth)
    assert rotation_error < 1.0
    assert translation_error < 0.1
    assert np.mean(result.inlier_mask == inliers) >= 0.95
    diag = result.diagnostics
    assert 0 < diag['n_seeds'] <= int(EstimatorConfig().seed_ratio * 1000)
    assert diag['best_hypothesis_inliers'] >= 90
    assert diag['leading_eigenvalue'] > 1.0
    assert all(isinstance(diag[k], float) for k in diag if k.endswith('_ms'))


def test_every_hypothesis_is_returned_most_inliers_first() -> None:
    src, dst, truth, _ = _problem(0)
    config = EstimatorConfig()
    result = sc2.sc2pcr(src, dst, config)
    hypotheses = result.hypotheses
    assert len(hypotheses) == result.diagnostics['n_seeds']
    assert hypotheses.T_target_source.shape == (len(hypotheses), 4, 4)
    assert np.all(np.diff(hypotheses.num_inliers) <= 0)
    assert hypotheses.num_inliers[0] == result.diagnostics['best_hypothesis_inliers']
    np.testing.assert_array_equal(
        hypotheses.num_inliers,
        sc2.count_inliers(hypotheses.T_target_source, src, dst, config.inlier_threshold),
    )
    # the winner is the first hypothesis after post-refinement
    refined, _ = sc2.post_refinement(
        hypotheses.T_target_source[0], src, dst, config.refine_threshold, config.refine_iterations
    )
    np.testing.assert_allclose(refined, result.transform, atol=1e-9)
    # the best distinct hypothesis is the truth
    kept = poses.distinct_hypotheses(hypotheses.T_target_source, 5, 5.0, 0.6)
    assert kept[0] == 0
    assert _errors(hypotheses.T_target_source[kept[0]], truth)[0] < 2.0
    assert estimate(src, dst, EstimatorConfig(kind='ransac')).hypotheses is None


def test_thresholds_come_from_config() -> None:
    src, dst, truth, _ = _problem(3, noise=0.2)
    loose = sc2.sc2pcr(src, dst, EstimatorConfig(inlier_threshold=1.0))
    tight = sc2.sc2pcr(src, dst, EstimatorConfig(inlier_threshold=0.2))
    assert tight.num_inliers < loose.num_inliers
    residual = np.linalg.norm(apply_transform(tight.transform, src) - dst, axis=1)
    np.testing.assert_array_equal(tight.inlier_mask, residual < 0.2)
    none = sc2.sc2pcr(src, dst, EstimatorConfig(refine_iterations=0))
    assert none.diagnostics['refine_iterations'] == 0
    assert _errors(none.transform, truth)[0] < 2.0


def test_non_finite_rows_are_ignored() -> None:
    src, dst, truth, _ = _problem(4)
    src[5] = np.nan
    dst[6, 1] = np.inf
    result = sc2.sc2pcr(src, dst, EstimatorConfig())
    assert _errors(result.transform, truth)[0] < 1.0
    assert not result.inlier_mask[5] and not result.inlier_mask[6]


@pytest.mark.parametrize('count', [0, 1, 2])
def test_too_few_correspondences_give_identity(count: int) -> None:
    points = np.arange(3.0 * count).reshape(count, 3)
    for kind in ('sc2pcr', 'ransac'):
        result = estimate(points, points + 1.0, EstimatorConfig(kind=kind))
        np.testing.assert_array_equal(result.transform, np.eye(4))
        assert result.inlier_mask.shape == (count,) and not result.inlier_mask.any()
        assert 'message' in result.diagnostics


@pytest.mark.parametrize('count', [3, 4, 40])
def test_identical_points_do_not_raise(count: int) -> None:
    points = np.ones((count, 3))
    result = sc2.sc2pcr(points, points + 2.0, EstimatorConfig(k1=30, k2=20))
    assert result.transform.shape == (4, 4) and np.isfinite(result.transform).all()
    assert result.inlier_mask.shape == (count,)


def test_small_inputs_clamp_k1_k2() -> None:
    src, dst, truth, _ = _problem(5, count=12, outlier_ratio=0.0)
    result = sc2.sc2pcr(src, dst, EstimatorConfig(k1=30, k2=20))
    assert _errors(result.transform, truth)[0] < 1.0
    assert result.num_inliers == 12


# -- baselines ------------------------------------------------------------------------------


def test_ransac_recovers_transform_with_50_percent_outliers() -> None:
    import open3d as o3d

    o3d.utility.random.seed(0)
    src, dst, truth, inliers = _problem(11, count=400, outlier_ratio=0.5)
    result = estimate(src, dst, EstimatorConfig(kind='ransac', ransac_iterations=100000))
    rotation_error, translation_error = _errors(result.transform, truth)
    assert rotation_error < 1.0
    assert translation_error < 0.2
    assert np.mean(result.inlier_mask == inliers) >= 0.95


def test_unknown_estimator_kind() -> None:
    with pytest.raises(ValueError, match='unknown estimator'):
        estimate(np.zeros((5, 3)), np.zeros((5, 3)), EstimatorConfig(kind='teaser'))


# -- real data ------------------------------------------------------------------------------


def test_dev_pair_with_nearest_neighbour_gedi_matches() -> None:
    files = [f for f in dev_pair_files() if f.name == '000003.npz']
    if not files:
        pytest.skip('dev pair 000003.npz not found')
    data = np.load(files[0])
    keep_src = np.isfinite(data['gedi_src']).all(axis=1)
    keep_dst = np.isfinite(data['gedi_dst']).all(axis=1)
    desc_src, desc_dst = data['gedi_src'][keep_src], data['gedi_dst'][keep_dst]
    squared = (desc_dst * desc_dst).sum(axis=1) - 2.0 * desc_src @ desc_dst.T
    nearest = np.argmin(squared, axis=1)  # nearest GEDI descriptor
    src = data['kpts_src'][keep_src]
    dst = data['kpts_dst'][keep_dst][nearest]
    result = sc2.sc2pcr(src, dst, EstimatorConfig())
    rotation_error, translation_error = _errors(result.transform, data['trans_gt'])
    assert rotation_error < 1.0 and translation_error < 0.3  # measured 0.24 deg, 0.13 m
    assert result.num_inliers >= 300  # 358 correspondences within 0.6 m under trans_gt


# -- the graph cap ---------------------------------------------------------------------------


def test_graph_rows_are_a_seeded_subset_or_everything() -> None:
    np.testing.assert_array_equal(sc2.graph_rows(5, 0), np.arange(5))
    np.testing.assert_array_equal(sc2.graph_rows(5, 9), np.arange(5))
    rows = sc2.graph_rows(1000, 100)
    assert rows.size == 100 and np.all(np.diff(rows) > 0) and rows[-1] < 1000
    np.testing.assert_array_equal(rows, sc2.graph_rows(1000, 100))


def test_graph_cap_builds_on_a_subset_and_scores_all() -> None:
    src, dst, truth, inliers = _problem(11, count=3000, outlier_ratio=0.9)
    result = sc2.sc2pcr(src, dst, EstimatorConfig(graph_size=600))
    assert result.diagnostics['graph_correspondences'] == 600
    assert result.inlier_mask.shape == (3000,)
    rotation_error, translation_error = _errors(result.transform, truth)
    assert rotation_error < 1.0 and translation_error < 0.3
    # inliers are counted on all 3000 correspondences, not only the graph's 600
    assert result.inlier_mask.sum() >= 0.95 * inliers.sum()


def test_sampled_graph_with_too_few_inliers_retries_on_the_full_graph() -> None:
    src, dst, truth, _ = _problem(14, count=3000, outlier_ratio=0.985)  # 45 inliers
    sampled_only = sc2.sc2pcr(src, dst, EstimatorConfig(graph_size=300, graph_retry_inliers=0))
    assert 'graph_retried' not in sampled_only.diagnostics
    assert _errors(sampled_only.transform, truth)[0] > 5.0  # ~7 inliers in the sample: lost
    result = sc2.sc2pcr(src, dst, EstimatorConfig(graph_size=300, graph_retry_inliers=30))
    assert result.diagnostics['graph_retried']
    assert result.diagnostics['sampled_best_inliers'] < 30
    assert result.diagnostics['graph_correspondences'] == 3000
    rotation_error, translation_error = _errors(result.transform, truth)
    assert rotation_error < 1.0 and translation_error < 0.3
    # plenty of inliers: the sample is kept
    src, dst, _, _ = _problem(13, count=3000, outlier_ratio=0.8)
    kept = sc2.sc2pcr(src, dst, EstimatorConfig(graph_size=300, graph_retry_inliers=30))
    assert 'graph_retried' not in kept.diagnostics

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

"""Hypothesis verification: known scores on tiny clouds, and the mirror pose of a street."""

from __future__ import annotations

from mlsemreg_ros.core.config import ConfigError, RegistrationConfig, VerificationConfig
from mlsemreg_ros.core.estimation.verification import (
    area_weights,
    choose,
    combined_score,
    dense_scores,
    label_compatibility,
)
from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.poses import distinct_hypotheses
from mlsemreg_ros.core.results import Landmarks, PreparedScan
from mlsemreg_ros.core.rigid import apply_transform, invert_transform
from mlsemreg_ros.datasets.synthetic_scene import motion
import numpy as np
import pytest

# SemanticKITTI learning ids
UNLABELED, CAR, ROAD, SIDEWALK, BUILDING, VEGETATION, TERRAIN, POLE = 0, 1, 9, 11, 13, 15, 17, 18


def _scan(
    points: np.ndarray,
    labels: np.ndarray,
    keypoints: np.ndarray | None = None,
    descriptors: np.ndarray | None = None,
) -> PreparedScan:
    """Build a prepared scan by hand (plain matching only needs keypoints and descriptors)."""
    keypoints = np.zeros((0, 3)) if keypoints is None else keypoints
    descriptors = (
        np.zeros((len(keypoints), 1), dtype=np.float32) if descriptors is None else descriptors
    )
    return PreparedScan(
        np.asarray(points, dtype=np.float64),
        np.asarray(labels, dtype=np.int32),
        keypoints,
        np.full(len(keypoints), -1),
        descriptors,
        np.zeros((len(keypoints), 20), dtype=bool),
        Landmarks.empty(),
    )


def _errors(T: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    cos = (np.trace(truth[:3, :3].T @ T[:3, :3]) - 1.0) / 2.0
    return (
        float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))),
        float(np.linalg.norm(T[:3, 3] - truth[:3, 3])),
    )


# -- scores: known answers on tiny clouds ------------------------------------------------


@pytest.fixture(scope='module')
def label_map() -> LabelMap:
    return LabelMap.load()


def _tiny() -> tuple[PreparedScan, PreparedScan]:
    target = _scan(
        [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], [ROAD, SIDEWALK, VEGETATION, UNLABELED]
    )
    source = _scan(
        [[0, 0, 0.1], [1, 0, 0.1], [2, 0, 0.1], [3, 0, 0.1], [10, 0, 0]],
        [ROAD, ROAD, TERRAIN, CAR, ROAD],
    )
    return source, target


def test_scores_have_the_known_answers_on_tiny_clouds(label_map):
    source, target = _tiny()
    config = VerificationConfig(compatible_classes=['vegetation~terrain'], range_exponent=0.0)
    labels = label_compatibility(label_map, config)
    hypotheses = np.stack([np.eye(4), motion(0.0, (1.0, 0.0, 0.0)), motion(0.0, (50.0, 0, 0))])
    overlap, agreement = dense_scores(
        hypotheses, source, target.points_tree(), target.labels, labels, config
    )
    # identity: 4 of 5 points overlap; of the 3 counted (the car lands on an unlabeled
    # point), road-road and terrain~vegetation agree, road-sidewalk does not
    # +1 m in x: 3 overlap (road->sidewalk, road->vegetation, terrain->unlabeled): 0 of 2
    # +50 m: nothing overlaps, nothing is counted: agreement 1 (geometry decides)
    np.testing.assert_allclose(overlap, [0.8, 0.6, 0.0])
    np.testing.assert_allclose(agreement, [2 / 3, 0.0, 1.0])
    np.testing.assert_allclose(combined_score(overlap, agreement, config), [0.8 * 2 / 3, 0, 0])
    weighted = VerificationConfig(overlap_weight=2.0, label_weight=0.0)
    np.testing.assert_allclose(combined_score(overlap, agreement, weighted), [0.64, 0.36, 0.0])


def _dense_scores(
    poses: np.ndarray,
    source: PreparedScan,
    target: PreparedScan,
    label_map: LabelMap,
    config: VerificationConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """Return :func:`dense_scores` of ``poses`` (H, 4, 4) under ``config``'s compatibility."""
    compatibility = label_compatibility(label_map, config)
    return dense_scores(poses, source, target.points_tree(), target.labels, compatibility, config)


def test_points_count_with_their_range_squared(label_map):
    # sensor at the origin; a near point (range 1) and a far one (range 3) on the road
    target = _scan([[1, 0, 0], [3, 0, 0]], [ROAD, ROAD])
    source = _scan([[1, 0, 0], [3, 0, 0]], [ROAD, SIDEWALK])
    for exponent, near, far in ((0.0, 0.5, 0.5), (1.0, 0.25, 0.75), (2.0, 0.1, 0.9)):
        config = VerificationConfig(range_exponent=exponent)
        np.testing.assert_allclose(area_weights(source.points, exponent), [near, far])
        # +2 m: only the near point lands on a target point (the far one)
        shifted = np.stack([np.eye(4), motion(0.0, (2.0, 0.0, 0.0))])
        overlap, agreement = _dense_scores(shifted, source, target, label_map, config)
        np.testing.assert_allclose(overlap, [1.0, near])
        np.testing.assert_allclose(agreement, [near, 1.0])  # the far point is sidewalk


def test_compatibility_and_ignored_classes_change_the_agreement(label_map):
    source, target = _tiny()
    strict = VerificationConfig(compatible_classes=[], range_exponent=0.0)  # no terrain~veg
    _, agreement = _dense_scores(np.eye(4)[None], source, target, label_map, strict)
    assert agreement[0] == pytest.approx(1 / 3)
    road_ignored = VerificationConfig(
        compatible_classes=['vegetation~terrain'],
        ignored_classes=['unlabeled', 'road'],
        range_exponent=0.0,
    )
    _, agreement = _dense_scores(np.eye(4)[None], source, target, label_map, road_ignored)
    assert agreement[0] == pytest.approx(1.0)  # only terrain~vegetation is left


def test_label_groups_and_bad_rules(label_map):
    config = VerificationConfig(compatible_classes=['vegetation~terrain~trunk'])
    table = label_compatibility(label_map, config).compatible
    veg, trunk = label_map.id_of('vegetation'), label_map.id_of('trunk')
    assert table[veg, trunk] and table[trunk, TERRAIN] and table[TERRAIN, veg]
    assert not table[ROAD, SIDEWALK] and table[ROAD, ROAD]
    np.testing.assert_array_equal(table, table.T)
    with pytest.raises(ConfigError, match='grass'):
        label_compatibility(label_map, VerificationConfig(compatible_classes=['grass~terrain']))
    with pytest.raises(ConfigError, match="form 'class~class'"):
        RegistrationConfig().replace({'verification.compatible_classes': ['vegetation']})
    with pytest.raises(ConfigError, match='grass'):
        Registration(
            RegistrationConfig().replace({'verification.compatible_classes': ['road~grass']})
        )


def test_choice_keeps_the_estimator_unless_clearly_beaten():
    assert choose(np.array([0.50, 0.52, 0.30]), 0.05) == 0  # +4 %: kept
    assert choose(np.array([0.50, 0.53, 0.30]), 0.05) == 1  # +6 %: replaced
    assert choose(np.array([0.0, 0.1]), 0.05) == 1
    assert choose(np.array([0.4]), 0.05) == 0


def test_distinct_hypotheses_drop_poses_within_the_success_bounds():
    transforms = np.stack(
        [
            np.eye(4),
            motion(3.0, (0.0, 0.0, 0.0)),  # within 5 deg and 0.6 m of 0: dropped
            motion(10.0, (0.0, 0.0, 0.0)),  # kept
            motion(0.0, (0.5, 0.0, 0.0)),  # within bounds of 0: dropped
            motion(0.0, (1.0, 0.0, 0.0)),  # kept
            motion(12.0, (0.2, 0.0, 0.0)),  # within bounds of 2: dropped
            motion(180.0, (0.0, 0.0, 0.0)),  # kept
        ]
    )
    np.testing.assert_array_equal(distinct_hypotheses(transforms, 10, 5.0, 0.6), [0, 2, 4, 6])
    np.testing.assert_array_equal(distinct_hypotheses(transforms, 2, 5.0, 0.6), [0, 2])
    np.testing.assert_array_equal(distinct_hypotheses(transforms, 10, 0.0, 0.0), np.arange(7))


# -- a symmetric street: the mirror pose wins the sparse count, loses on labels -----------


def _symmetric_street(
    rng: np.random.Generator, density: float = 4.0
) -> tuple[np.ndarray, np.ndarray]:
    """
    Sample a street along x, its geometry symmetric under a 180 deg turn about z, not its labels.

    Road for |y| < 4; sidewalk on the +y side, terrain on the -y side; facades at y = +10
    (building) and hedges at y = -10 (vegetation) with irregular heights h(x) and h(-x), so
    ``(x, y, z) -> (-x, -y, z)`` maps the surfaces onto themselves (and nothing else does).
    """
    ground = np.column_stack(
        [
            rng.uniform(-30, 30, int(density * 60 * 20)),
            rng.uniform(-10, 10, int(density * 60 * 20)),
            np.zeros(int(density * 60 * 20)),
        ]
    )
    y = ground[:, 1]
    ground_labels = np.where(np.abs(y) < 4, ROAD, np.where(y > 0, SIDEWALK, TERRAIN))
    edges = np.linspace(-30, 30, 9)
    heights = rng.uniform(2.0, 9.0, 8)

    def wall(side: float) -> np.ndarray:
        x = rng.uniform(-30, 30, int(density * 60 * 6))
        height = heights[np.clip(np.searchsorted(edges, side * x) - 1, 0, 7)]
        z = rng.uniform(0, 1, x.size) * height
        return np.column_stack([x, np.full(x.size, 10.0 * side), z])

    plus, minus = wall(1.0), wall(-1.0)
    points = np.concatenate([ground, plus, minus])
    labels = np.concatenate(
        [ground_labels, np.full(len(plus), BUILDING), np.full(len(minus), VEGETATION)]
    ).astype(np.int32)
    return points, labels


def make_street_pair() -> dict:
    """Dense scans of the street and sparse one-hot-matched keypoints: 40 true, 60 mirror."""
    rng = np.random.default_rng(7)
    truth = motion(10.0, (3.0, 0.5, 0.0))  # T_target_source
    mirror = motion(180.0, (0.0, 0.0, 0.0)) @ truth  # the street's symmetry after the truth
    world_target, target_labels = _symmetric_street(rng)
    world_source, source_labels = _symmetric_street(rng)  # an independent sample
    source_points = apply_transform(invert_transform(truth), world_source)
    source_points += rng.normal(0.0, 0.02, source_points.shape)
    count = 200
    source_kp = source_points[rng.choice(len(source_points), count, replace=False)]
    target_kp = world_target[rng.choice(len(world_target), count, replace=False)]  # outliers
    target_kp[:40] = apply_transform(truth, source_kp[:40])
    target_kp[40:100] = apply_transform(mirror, source_kp[40:100])
    target_kp[:100] += rng.normal(0.0, 0.05, (100, 3))
    one_hot = np.eye(count, dtype=np.float32)  # keypoint i of the source matches i of the target
    source = _scan(source_points, source_labels, source_kp, one_hot)
    target = _scan(world_target, target_labels, target_kp, one_hot)
    return {'source': source, 'target': target, 'truth': truth, 'mirror': mirror}


@pytest.fixture(scope='module')
def street_pair() -> dict:
    return make_street_pair()


def _register(pair: dict, **overrides: object):
    flat = {
        'semantic.enabled': False,
        'bev_search.enabled': False,  # verification alone (tested with it below)
        **{f'verification.{k}': v for k, v in overrides.items()},
    }
    return Registration(RegistrationConfig().replace(flat)).register(
        pair['source'], pair['target']
    )


def test_without_verification_the_mirror_pose_wins_on_sparse_inliers(street_pair):
    result = _register(street_pair, enabled=False)
    assert _errors(result.transform, street_pair['mirror'])[0] < 2.0
    assert result.num_inliers >= 55
    assert 'verification_ms' not in result.timings_ms


def test_verification_picks_the_true_pose_by_label_agreement(street_pair):
    result = _register(street_pair)
    re, te = _errors(result.transform, street_pair['truth'])
    assert re < 1.0 and te < 0.3
    d = result.diagnostics
    assert d['verification_switched'] and d['verification_hypotheses'] >= 2
    chosen = next(
        i
        for i in range(d['verification_hypotheses'])
        if d[f'verification_h{i}_rank'] == d['verification_chosen_rank']
    )
    assert chosen != 0
    # the estimator's choice (the mirror) has more sparse inliers and as much overlap ...
    assert d['verification_h0_inliers'] > d[f'verification_h{chosen}_inliers'] >= 35
    assert d[f'verification_h{chosen}_overlap'] > 0.8
    assert abs(d['verification_h0_overlap'] - d[f'verification_h{chosen}_overlap']) < 0.02
    # ... but puts sidewalk on terrain and building on vegetation
    assert d['verification_h0_label_agreement'] < 0.7
    assert d[f'verification_h{chosen}_label_agreement'] > 0.95
    assert result.timings_ms['verification_ms'] > 0.0


def test_geometry_alone_cannot_tell_the_mirror_from_the_truth(street_pair):
    result = _register(street_pair, label_weight=0.0)
    assert not result.success  # ambiguous: neither pose is accepted
    assert not result.diagnostics['verification_switched']
    # the verification keeps the mirror, and the covisible choice among refused poses
    # (stage 6b) keeps it too: the truth has no more evidence than it
    assert _errors(result.transform, street_pair['mirror'])[0] < 2.0
    assert not result.diagnostics['covisible_switched']


def test_one_hypothesis_verifies_only_the_estimator_choice(street_pair):
    result = _register(street_pair, hypotheses=1)
    assert result.diagnostics['verification_hypotheses'] == 1
    assert _errors(result.transform, street_pair['mirror'])[0] < 2.0


def test_a_refused_mirror_sends_the_scans_to_the_bev_search(street_pair):
    flat = {'semantic.enabled': False, 'verification.hypotheses': 1}
    result = Registration(RegistrationConfig().replace(flat)).register(
        street_pair['source'], street_pair['target']
    )
    assert not result.success  # with every stage: still refused, so nothing wrong published
    d = result.diagnostics
    assert d['bev_search_used']  # the mirror's label agreement is refused
    assert d['bev_search_label_agreement'] > 0.95
    # the BEV search's pose survives the covisible choice among refused poses (stage 6b):
    # it once swapped it for a pose 180 deg and 20 m off with 0 inliers (issue 30)
    re, te = _errors(result.transform, street_pair['truth'])
    assert re < 1.0 and te < 0.3
    assert result.num_inliers >= 35


# -- distinctive structure: the per-scan sides are made once, for those very arrays -------


def _poles(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Five poles (20 points each) on a road plane, 30 m across."""
    rng = np.random.default_rng(seed)
    feet = rng.uniform(-15.0, 15.0, (5, 2))
    poles = np.concatenate(
        [np.column_stack([np.tile(f, (20, 1)), np.linspace(0.0, 3.0, 20)]) for f in feet]
    )
    road = np.column_stack([rng.uniform(-20.0, 20.0, (400, 2)), np.zeros(400)])
    points = np.concatenate([poles, road])
    labels = np.concatenate([np.full(len(poles), POLE), np.full(len(road), ROAD)])
    return points, labels.astype(np.int32)


def test_distinctive_scores_are_the_same_from_the_kept_sides():
    """The kept sides give the fresh answer; other labels on the same points are not served."""
    from mlsemreg_ros.core.estimation import verification

    points, labels = _poles(3)
    truth = motion(20.0, (4.0, -2.0, 0.0))
    source = _scan(points, labels)
    target = _scan(apply_transform(truth, points), labels)
    distinctive = np.zeros(20, dtype=bool)
    distinctive[POLE] = True
    poses = np.stack([truth, np.eye(4), motion(20.0, (6.0, -2.0, 0.0))])
    first = verification.distinctive_scores(poses, source, target, distinctive, 0.5)
    again = verification.distinctive_scores(poses, source, target, distinctive, 0.5)
    fresh = verification._DistinctiveSides().side(source, distinctive, source=True)
    kept = verification._DISTINCTIVE_SIDES.side(source, distinctive, source=True)
    assert kept is verification._DISTINCTIVE_SIDES.side(source, distinctive, source=True)
    np.testing.assert_array_equal(kept.member, fresh.member)
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(a, b)
    assert first[1][0] == 5 and first[0][0] == 1.0  # the truth lines up all five poles
    assert first[1][1] < 5
    # the same points without pole labels: nothing distinctive, not the kept side's answer
    bare = _scan(points, np.full(len(points), ROAD, dtype=np.int32))
    bare.points = source.points
    share, objects, in_view = verification.distinctive_scores(
        poses, bare, target, distinctive, 0.5
    )
    assert not share.any() and not objects.any() and not in_view.any()

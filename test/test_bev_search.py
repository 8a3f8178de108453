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

"""The semantic BEV search: known answers, properties, and the pair it rescues."""

from __future__ import annotations

from dataclasses import replace

from mlsemreg_ros.core.config import ConfigError, RegistrationConfig
from mlsemreg_ros.core.estimation import bev_search
from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.rigid import apply_transform, invert_transform
from mlsemreg_ros.datasets.synthetic_scene import motion, scan_at, street_scene
import numpy as np
import pytest

BUILDING, VEGETATION, POLE = 13, 15, 18
SEARCH = replace(RegistrationConfig().bev_search, hypotheses=16)  # 1 m cells, 6 -> 2 deg


@pytest.fixture(scope='module')
def lookup() -> np.ndarray:
    label_map = LabelMap.load()
    return bev_search.channel_lookup(label_map, RegistrationConfig().bev_search)


def _errors(T: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    cos = (np.trace(truth[:3, :3].T @ T[:3, :3]) - 1.0) / 2.0
    return (
        float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))),
        float(np.linalg.norm(T[:3, 3] - truth[:3, 3])),
    )


def _l_shaped_yard() -> tuple[np.ndarray, np.ndarray]:
    """Two walls (building), a hedge (vegetation) and three poles: no symmetry."""
    rng = np.random.default_rng(3)
    wall_a = np.column_stack([rng.uniform(-20, 25, 3000), np.full(3000, 12.0), np.zeros(3000)])
    wall_b = np.column_stack([np.full(2000, -20.0), rng.uniform(-15, 12, 2000), np.zeros(2000)])
    hedge = np.column_stack([rng.uniform(0, 18, 1500), np.full(1500, -9.0), np.zeros(1500)])
    poles = np.repeat([[6.0, 3.0, 0.0], [-11.0, -6.0, 0.0], [15.0, -2.0, 0.0]], 40, axis=0)
    points = np.concatenate([wall_a, wall_b, hedge, poles])
    points[:, 2] = rng.uniform(0.5, 4.0, len(points))
    labels = np.repeat([BUILDING, BUILDING, VEGETATION, POLE], [3000, 2000, 1500, 120])
    return points, labels.astype(np.int32)


# -- known answers ------------------------------------------------------------------------


def test_a_scan_on_itself_peaks_at_the_identity_with_one_per_channel(lookup):
    points, labels = _l_shaped_yard()
    poses, scores = bev_search.bev_hypotheses(points, labels, points, labels, lookup, SEARCH)
    re, te = _errors(poses[0], np.eye(4))
    assert re < 1e-9 and te < 1e-9
    # three channels, each a perfect cosine match of its occupied cells
    assert scores[0] == pytest.approx(3.0, abs=1e-4)
    assert np.all(np.diff(scores) <= 1e-6)  # best first


def test_the_yard_moved_by_a_known_pose_is_found(lookup):
    points, labels = _l_shaped_yard()
    truth = motion(37.0, (6.0, -4.0, 0.3))  # T_target_source
    source = apply_transform(invert_transform(truth), points)
    poses, _ = bev_search.bev_hypotheses(source, labels, points, labels, lookup, SEARCH)
    re, te = _errors(poses[0], truth)
    # a coarse pose for the refinement: within two yaw steps and two cells (z not searched)
    assert re <= 4.01 and te < 2.0 + 0.3


def test_peaks_near_a_better_one_are_suppressed_across_zero_yaw():
    """The peaks go through the estimator's own distinct-pose rule (core/estimation/sc2pcr.py)."""
    from mlsemreg_ros.core.poses import distinct_hypotheses

    peaks = np.array(  # (score, yaw, tx, ty), best first
        [
            [0.9, 12.0, 1.0, 0.0],
            [0.8, 359.0, 20.0, 0.0],  # far in translation: kept
            [0.7, 14.0, 1.5, 0.5],  # within 4 deg / 2 m of the best: dropped
            [0.6, 200.0, 1.0, 0.0],  # far in yaw: kept
            [0.5, 10.0, 0.0, 5.0],  # near the best in yaw, not in translation: kept
            [0.4, 3.0, 21.0, 0.0],  # within 4 deg (across 0) / 2 m of the 0.8 peak: dropped
        ]
    )
    poses = bev_search.z_up_poses(peaks[:, 1], peaks[:, 2], peaks[:, 3])
    np.testing.assert_array_equal(distinct_hypotheses(poses, 10, 4.0, 2.0), [0, 1, 3, 4])
    assert len(distinct_hypotheses(poses, 2, 4.0, 2.0)) == 2


def test_no_searched_class_gives_no_hypothesis(lookup):
    points, _ = _l_shaped_yard()
    road = np.full(len(points), 9, dtype=np.int32)
    poses, scores = bev_search.bev_hypotheses(points, road, points, road, lookup, SEARCH)
    assert poses.shape == (0, 4, 4) and scores.shape == (0,)


def test_bad_channel_rules_are_refused():
    with pytest.raises(ConfigError, match=r'bev_search\.classes'):
        RegistrationConfig().replace({'bev_search.classes': []})
    with pytest.raises(ConfigError, match=r'bev_search\.classes'):
        RegistrationConfig().replace({'bev_search.classes': ['building~']})
    with pytest.raises(ConfigError, match='unknown class'):
        Registration(RegistrationConfig().replace({'bev_search.classes': ['castle']}))


# -- properties ---------------------------------------------------------------------------


@pytest.mark.parametrize('yaw, tx, ty', [(0.0, 12.0, 3.0), (90.0, -5.0, 8.0), (211.0, 3.0, -17.0)])
def test_the_best_peak_follows_the_motion(lookup, yaw, tx, ty):
    """Equivariance: moving the source by a yaw and a shift moves the best peak with it."""
    points, labels = _l_shaped_yard()
    truth = motion(yaw, (tx, ty, 0.0))
    source = apply_transform(invert_transform(truth), points)
    poses, _ = bev_search.bev_hypotheses(source, labels, points, labels, lookup, SEARCH)
    re, te = _errors(poses[0], truth)
    assert re <= 4.01 and te <= 2.0


def test_translations_beyond_the_searched_range_are_never_proposed(lookup):
    points, labels = _l_shaped_yard()
    search = replace(SEARCH, max_translation=5.0, hypotheses=64)
    source = apply_transform(invert_transform(motion(0.0, (30.0, 0.0, 0.0))), points)
    poses, _ = bev_search.bev_hypotheses(source, labels, points, labels, lookup, search)
    assert np.all(np.abs(poses[:, :2, 3]) <= 5.0 + 1e-9)


# -- in the pipeline: the estimator's pose is refused, the search finds the truth ------------


@pytest.fixture(scope='module')
def street_far_apart() -> dict:
    """Two scans of the generated street 18 m apart (random descriptors, plain matching)."""
    world, labels = street_scene(5)
    truth = motion(6.0, (18.0, 1.0, 0.0))  # T_target_source = the source sensor's pose
    target_points, target_labels = scan_at(world, labels, np.eye(4), 1)
    source_points, source_labels = scan_at(world, labels, truth, 2)
    return {
        'source': (source_points, source_labels),
        'target': (target_points, target_labels),
        'truth': truth,
    }


def _register(pair: dict, **overrides: object):
    config = RegistrationConfig().replace({'semantic.enabled': False, **overrides})
    registration = Registration(config)
    rng = np.random.default_rng(0)
    scans = []
    for side in ('source', 'target'):
        points, labels = pair[side]
        keypoints = points[rng.choice(len(points), 1000, replace=False)]
        noise = rng.random((1000, 33)).astype(np.float32)  # no geometric information
        scans.append(registration.prepare(points, labels, keypoints=keypoints, descriptors=noise))
    return registration.register(*scans)


def test_without_the_search_useless_correspondences_give_no_pose(street_far_apart):
    result = _register(street_far_apart, **{'bev_search.enabled': False})
    assert not result.success
    assert 'bev_search_ms' not in result.timings_ms
    # the coarse pose: a refused registration keeps its fine alignment when that holds the
    # dense score, and here GICP pulls the 7.9 deg / 1.2 m pose onto the truth (still refused)
    re, te = _errors(result.estimate, street_far_apart['truth'])
    assert re > 5.0 or te > 0.6


def test_the_search_finds_the_pose_the_correspondences_miss(street_far_apart):
    result = _register(street_far_apart, **{'covisibility.accept_overlap': 0.0})
    d = result.diagnostics
    assert d['bev_search_used'] and result.timings_ms['bev_search_ms'] > 0.0
    re, te = _errors(result.transform, street_far_apart['truth'])
    assert re < 1.0 and te < 0.3  # refined by GICP even though refused
    assert d['bev_search_overlap'] > 0.5 and d['bev_search_label_agreement'] > 0.9
    # random descriptors leave next to no sparse inliers: the sparse evidence is insufficient
    assert not result.success and 'inliers' in result.message
    assert 'bev_search pose' in result.message


def test_the_searched_pose_is_accepted_where_both_scans_see(street_far_apart):
    # stage 9 (covisible acceptance, on by default) accepts the refined searched pose on its
    # covisible overlap, which the sparse inliers of random descriptors could not
    result = _register(street_far_apart)
    assert result.success and result.diagnostics.get('covisible_accepted')
    re, te = _errors(result.transform, street_far_apart['truth'])
    assert re < 1.0 and te < 0.3


def test_weak_evidence_sends_an_accepted_pose_to_the_search_too(street_far_apart):
    semantic = {'semantic.enabled': True, 'keypoints.count': 1000}
    plain = _register(street_far_apart, **semantic)
    assert plain.success and 'bev_search_ms' not in plain.timings_ms
    weak = _register(street_far_apart, **semantic, **{'bev_search.weak_inliers': 100000})
    assert 'bev_search_ms' in weak.timings_ms and weak.success
    assert _errors(weak.transform, street_far_apart['truth'])[1] < 0.3


def test_labels_outside_the_map_are_not_searched(lookup):
    points, labels = _l_shaped_yard()
    odd = labels.copy()
    odd[labels == POLE] = 1000  # out of the learning ids: must not become traffic-sign
    odd[labels == VEGETATION] = -5
    with_odd = bev_search.bev_hypotheses(points, odd, points, labels, lookup, SEARCH)
    walls_only = labels.copy()
    walls_only[labels != BUILDING] = 9  # road: not searched
    reference = bev_search.bev_hypotheses(points, walls_only, points, labels, lookup, SEARCH)
    np.testing.assert_allclose(with_odd[1], reference[1])


@pytest.mark.parametrize('yaw', [37.0, 143.0, 290.0])
def test_coarse_to_fine_finds_what_the_full_search_finds(lookup, yaw):
    points, labels = _l_shaped_yard()
    # the walls at whole metres would lie on cell borders at the true pose, where a
    # rotation's last bit picks the cell (a quarter turn read from another yaw's grid
    # may pick the other): cell centres instead
    points[:, :2] += 0.5
    truth = motion(yaw, (4.0, -6.0, 0.0))
    source = apply_transform(invert_transform(truth), points)
    full, full_scores = bev_search.bev_hypotheses(
        source, labels, points, labels, lookup, replace(SEARCH, coarse_factor=1)
    )
    fast, fast_scores = bev_search.bev_hypotheses(
        source, labels, points, labels, lookup, replace(SEARCH, coarse_factor=3, coarse_yaws=4)
    )
    np.testing.assert_allclose(fast[0], full[0])
    assert fast_scores[0] == pytest.approx(full_scores[0])


@pytest.mark.parametrize('yaw', [0.0, 37.0, 143.0])
def test_the_quarter_turns_are_read_from_their_yaws_transform(lookup, yaw):
    # the grid of the yaw 90, 180 or 270 deg on is the yaw's grid turned (but for points
    # on a cell border: here none), so one forward transform serves the four yaws
    points, labels = _l_shaped_yard()
    points[:, :2] += 0.25  # off the cell borders
    truth = motion(yaw + 270.0, (4.0, -6.0, 0.0))
    source = apply_transform(invert_transform(truth), points)
    grid = bev_search.BevGrid.make(SEARCH.cell_size, SEARCH.radius, SEARCH.max_translation)
    channel = bev_search._channels(labels, lookup)
    correlator = bev_search.Correlator(source[:, :2], channel, points[:, :2], channel, grid, 3)
    yaws = np.mod(yaw + np.array([0.0, 90.0, 180.0, 270.0, 45.0]), 360.0)
    together = correlator.peaks(yaws, 5)
    alone = np.concatenate([correlator.peaks(yaws[[index]], 5) for index in range(yaws.size)])
    # yaw by yaw the same scores (equal ones may change places: rounding) and best shift
    np.testing.assert_array_equal(together[:, 1], alone[:, 1])
    np.testing.assert_allclose(together[:, 0], alone[:, 0], atol=1e-5)
    np.testing.assert_array_equal(together[::5, 2:], alone[::5, 2:])
    best = together[np.argmax(together[:, 0])]
    assert best[1] == yaws[3] and abs(best[2] - 4.0) <= 1.0 and abs(best[3] + 6.0) <= 1.0


def test_quarter_turn_groups_take_each_yaw_once():
    yaws = np.array([0.0, 90.0, 180.0, 45.0, 270.0, 0.0, 315.0, 90.0, 359.0])
    groups = bev_search.quarter_turn_groups(yaws)
    np.testing.assert_array_equal(
        groups, [[0, 1, 2, 4], [3, -1, -1, 6], [5, 7, -1, -1], [8, -1, -1, -1]]
    )
    assert sorted(groups[groups >= 0]) == list(range(yaws.size))


def test_the_fine_yaws_lie_between_the_coarse_ones():
    class Recorder:
        def __init__(self) -> None:
            self.calls: list[np.ndarray] = []

        def peaks(self, yaws: np.ndarray, k: int) -> np.ndarray:
            self.calls.append(yaws)
            score = np.cos(np.radians(yaws - 100.0))  # best at 100 deg
            return np.column_stack([score, yaws, np.zeros_like(yaws), np.zeros_like(yaws)])

    recorder = Recorder()
    bev_search.yaw_search(recorder, 2.0, 1, 3, 2)
    coarse, fine = recorder.calls
    np.testing.assert_allclose(coarse, np.arange(0.0, 360.0, 6.0))
    np.testing.assert_allclose(fine, [94.0, 98.0, 100.0, 104.0])  # around 96 and 102


def test_a_search_grid_too_large_for_memory_is_refused():
    with pytest.raises(ConfigError, match=r'bev_search: .* 1000 cells'):
        RegistrationConfig().replace({'bev_search.max_translation': 450.0})
    RegistrationConfig().replace({'bev_search.max_translation': 200.0})  # 500 cells: fine

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
Acceptance of a refused far pose where both scans see (stage 7b, issue 30).

The rule (core/estimation/covisible_acceptance.py) on hand-made numbers, and the stage
(core/stages/covisible_acceptance.py) on hand-made streets 60 m long: one whose facades
have gaps and setbacks (the right pose is accepted), one whose walls run straight along the
whole street (every slide fits as well: refused).
"""

from __future__ import annotations

from types import SimpleNamespace

from mlsemreg_ros.core.alignment.fine_alignment import correction_refusal, RefinementBounds
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.estimation.confidence import slid_poses
from mlsemreg_ros.core.estimation.covisibility import mutual_covisible_overlap
from mlsemreg_ros.core.estimation.covisible_acceptance import (
    acceptance_refusal,
    best_eligible,
    best_rivals,
    CovisibleEvidence,
    localizability_refusal,
    tilt_refusal,
)
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.stages.context import RegistrationContext
from mlsemreg_ros.core.stages.covisibility import covisible_side
from mlsemreg_ros.core.stages.covisible_acceptance import CovisibleAcceptanceStage
import numpy as np
import pytest
from test_long_range import BUILDING, long_street, pose, scan, straight_street

REFUSED = '6 inliers < estimator.min_inliers=40'


def evidence(overlap=0.99, checked=0.1, rival=0.9, slide=0.9, tilt=2.0) -> CovisibleEvidence:
    return CovisibleEvidence(overlap, checked, rival, 0.1, slide, 0.1, tilt)


def test_the_rule_accepts_a_pose_clearly_above_its_rivals():
    covis = RegistrationConfig().covisibility
    assert acceptance_refusal(evidence(), covis) == ''
    assert acceptance_refusal(evidence(rival=0.0, slide=0.0), covis) == ''  # none measured


@pytest.mark.parametrize(
    'changed, word',
    [
        ({'overlap': 0.96}, 'accept_overlap'),
        ({'checked': 0.02}, 'accept_checked'),
        # the 40 m pair 000006_000007 (GEDI): 1.5 m off, a distinct candidate as good
        ({'overlap': 0.985, 'rival': 0.985}, 'distinct candidate'),
        ({'overlap': 0.98, 'rival': 0.96}, 'distinct candidate'),
        # a straight street: the pose slid 5 m fits the free space as well
        ({'slide': 0.97}, 'slide'),
    ],
)
def test_the_rule_refuses(changed, word):
    reason = acceptance_refusal(evidence(**changed), RegistrationConfig().covisibility)
    assert word in reason


@pytest.mark.parametrize(
    ('overlap', 'near', 'checked', 'refused'),
    [
        (0.989, 0.998, 0.25, True),  # 40 m FPFH 000006_000007, 1.55 m off: 0.0025 more
        (0.987, 0.998, 0.05, False),  # a right 60 m pose (000010_000012): 0.0006, noise
        (0.992, 0.994, 0.14, False),  # a right 60 m pose (000009_000011)
        (1.000, 0.996, 0.46, False),  # the slides fit worse
        (0.989, 0.0, 0.25, False),  # no slides measured
    ],
)
def test_a_pose_a_near_slide_fits_better_is_refused(overlap, near, checked, refused):
    found = CovisibleEvidence(overlap, checked, 0.9, 0.1, 0.9, 0.1, 2.0, near)
    reason = acceptance_refusal(found, RegistrationConfig().covisibility)
    assert ('accept_climb' in reason) == refused, reason


def test_the_rule_is_off_at_zero():
    covis = RegistrationConfig().covisibility
    covis.accept_overlap = 0.0
    assert 'off' in acceptance_refusal(evidence(), covis)


def test_tilt_refusal():
    covis = RegistrationConfig().covisibility
    assert tilt_refusal(6.6, covis) == ''  # the most tilted right 60 m pose
    assert 'accept_tilt' in tilt_refusal(23.3, covis)  # an unrelated pair's wrong pose
    assert tilt_refusal(float('nan'), covis)


def test_best_rivals_leave_out_the_pose_itself_and_unchecked_candidates():
    T = np.repeat(np.eye(4)[None], 5, axis=0)
    T[1, 0, 3] = 1.0  # a variant of the pose (within confidence.rival_translation)
    T[2, 0, 3] = 10.0
    T[3, 1, 3] = 20.0
    T[4, 0, 3] = 30.0
    overlap = np.array([1.0, 0.99, 0.8, 0.9, 0.95])
    checked = np.array([0.1, 0.1, 0.1, 0.1, 0.01])  # the last one: too little checked
    found = best_rivals(np.eye(4), T, overlap, checked, 0.03, 10.0, 3.0, 8)
    assert list(found) == [3, 2]
    assert list(best_rivals(np.eye(4), T, overlap, checked, 0.03, 10.0, 3.0, 1)) == [3]
    assert best_eligible(overlap[2:], checked[2:], 0.03) == (0.9, 0.1)
    assert best_eligible(overlap[4:], checked[4:], 0.03) == (0.0, 0.0)


def facade_street(seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Return the poles' street with facades of 4-12 m, gaps of 2-6 m, setbacks of 8.5-12 m."""
    world, labels = long_street()
    rng = np.random.default_rng(seed)
    parts, names = [world], [labels]
    x = -25.0
    while x < 85.0:
        length = rng.uniform(4.0, 12.0)
        for side in (-1.0, 1.0):
            count = int(60 * length)
            wall = np.column_stack(
                [
                    rng.uniform(x, x + length, count),
                    np.full(count, side * rng.uniform(8.5, 12.0)),
                    rng.uniform(0.0, 6.0, count),
                ]
            )
            parts.append(wall)
            names.append(np.full(count, BUILDING))
        x += length + rng.uniform(2.0, 6.0)
    return np.concatenate(parts), np.concatenate(names)


def judged(
    world,
    labels,
    chosen_offset: np.ndarray,
    pool_offsets: list[np.ndarray],
    degeneracy_ratio: float | None = None,
    config: RegistrationConfig | None = None,
):
    """Run the stage on a refused 60 m pose (truth moved by ``chosen_offset``); its context."""
    registration = Registration(config if config is not None else RegistrationConfig())
    T_ws, T_wt = pose(0.0, 0.0, 1.7, 0.0), pose(60.0, -1.0, 1.7, 175.0)
    source = registration.prepare(*scan(world, labels, T_ws))
    target = registration.prepare(*scan(world, labels, T_wt))
    truth = np.linalg.inv(T_wt) @ T_ws
    chosen = truth @ chosen_offset
    candidates = np.stack([chosen] + [truth @ offset for offset in pool_offsets])
    cfg = registration.config
    sides = [covisible_side(scan_, 2.0, cfg.verification) for scan_ in (source, target)]
    context = RegistrationContext(source, target, True, cfg, None)
    context.label_names = registration.label_map.names
    context.transform = chosen
    context.alignment = SimpleNamespace(T_target_source=chosen, correction=np.eye(4))
    context.refusal = REFUSED
    context.pool = SimpleNamespace(transforms=lambda: candidates)
    context.covisible_pool = mutual_covisible_overlap(candidates, *sides, 0.6, 1.0)
    if degeneracy_ratio is not None:  # what the fine alignment measured (stages/fine_alignment)
        context.diagnostics['degeneracy_ratio'] = degeneracy_ratio
    stage = CovisibleAcceptanceStage()
    assert stage.wanted(context)
    stage.run(context)
    return context


def test_the_right_60_m_pose_is_accepted_where_both_scans_see():
    """Facades with gaps: the truth fits the free space, its slides and a turn do not."""
    world, labels = facade_street()
    turned, slid = pose(0, 0, 0, 30.0), pose(6.0, 0, 0, 0)
    context = judged(world, labels, np.eye(4), [pose(0.3, 0, 0, 0.5), turned, slid])
    diagnostics = context.diagnostics
    assert context.refusal == '', diagnostics
    assert diagnostics['covisible_accepted']
    assert diagnostics['covisible_accept_overlap'] >= 0.97
    assert diagnostics['covisible_accept_rival_overlap'] <= 0.95  # the 6 m slide
    assert context.message.startswith('accepted where both scans see')


def test_a_tilted_pose_is_not_accepted():
    world, labels = facade_street()
    context = judged(world, labels, pose(0, 0, 0, 0.0, roll=15.0), [pose(0, 0, 0, 30.0)])
    assert context.refusal == REFUSED
    assert 'accept_tilt' in context.diagnostics['covisible_accept_refusal']


def test_a_pose_slid_along_a_weak_direction_is_not_accepted():
    """
    The covisible overlap cannot see a slide of a metre: the pose must be localizable.

    (A simulated 80 m pair, ``mlsemreg simulate --realism field --seed 3`` frames 25 and 112,
    FPFH: accepted here 0.90 m off along the street, covisible overlap 1.000, best distinct
    candidate 0.918, degeneracy ratio 0.006; docs/hard_pairs.md, margins.)
    """
    world, labels = facade_street()
    slid = pose(0.9, 0.0, 0.0, 0.0)  # along the street
    no_climb = RegistrationConfig().replace({'covisibility.accept_near_slide': 0.0})
    context = judged(world, labels, slid, [pose(0, 0, 0, 30.0)], config=no_climb)
    assert context.refusal == '' and context.diagnostics['covisible_accept_overlap'] >= 0.97
    context = judged(world, labels, slid, [pose(0, 0, 0, 30.0)], 0.006, no_climb)
    assert context.refusal == REFUSED
    assert 'accept_localizability' in context.diagnostics['covisible_accept_refusal']
    # the near slides see it too: slid back by a metre, the pose fits more of the surface
    context = judged(world, labels, slid, [pose(0, 0, 0, 30.0)])
    assert context.refusal == REFUSED
    assert 'accept_climb' in context.diagnostics['covisible_accept_refusal']
    right = judged(world, labels, np.eye(4), [pose(0, 0, 0, 30.0)], degeneracy_ratio=0.023)
    assert right.refusal == ''  # the least localizable right KITTI 60 m pose


def test_localizability_refusal():
    covis = RegistrationConfig().covisibility
    assert localizability_refusal(None, covis) == ''  # not measured
    assert localizability_refusal(0.023, covis) == ''
    assert 'accept_localizability=0.01' in localizability_refusal(0.006, covis)
    assert localizability_refusal(float('nan'), covis)
    covis.accept_localizability = 0.0
    assert localizability_refusal(0.001, covis) == ''


def test_a_straight_street_keeps_the_pose_refused():
    """Walls that run the whole street: the pose slid 5 m fits as well, so nothing decides."""
    world, labels = straight_street()
    context = judged(world, labels, np.eye(4), [pose(0, 0, 0, 30.0)])
    assert context.refusal == REFUSED
    assert 'slide' in context.diagnostics['covisible_accept_refusal']


def test_a_later_doubt_keeps_the_pose_refused():
    world, labels = facade_street()
    registration_doubt = 'the level check refused it'
    context = judged(world, labels, np.eye(4), [pose(0, 0, 0, 30.0)])
    assert context.refusal == ''
    context.refusal, context.doubts = REFUSED, [registration_doubt]
    CovisibleAcceptanceStage().run(context)
    assert context.refusal == REFUSED


def test_the_refinement_s_move_from_the_coarse_pose_is_no_doubt_here():
    """The refined pose is the one judged: the coarse pose's distance to it does not count."""
    world, labels = facade_street()
    context = judged(world, labels, np.eye(4), [pose(0, 0, 0, 30.0)])
    moved = pose(5.0, 0.0, 0.0, 20.0)
    context.alignment.correction = moved
    bounds = RefinementBounds.of(context.config.odometry)
    context.refusal, context.doubts = REFUSED, [correction_refusal(context.alignment, bounds)]
    assert context.doubts[0]
    CovisibleAcceptanceStage().run(context)
    assert context.refusal == '' and context.doubts == []


def test_the_stage_never_runs_without_the_pair_s_fine_alignment():
    """The odometry registers with refine=False: no alignment, so nothing is accepted here."""
    context = RegistrationContext(None, None, False, RegistrationConfig(), None)
    context.refusal, context.covisible_pool = REFUSED, (np.ones(1), np.ones(1))
    context.transform = np.eye(4)
    assert not CovisibleAcceptanceStage().wanted(context)


def test_the_stage_is_off_at_zero():
    config = RegistrationConfig()
    config.covisibility.accept_overlap = 0.0
    context = RegistrationContext(None, None, True, config, None)
    context.refusal, context.covisible_pool = REFUSED, (np.ones(1), np.ones(1))
    context.alignment = SimpleNamespace(T_target_source=np.eye(4))
    context.transform = np.eye(4)
    assert not CovisibleAcceptanceStage().wanted(context)


def test_slides_of_a_straight_street_fit_as_well_as_the_truth():
    """The measurement behind the straight-street test (covisible overlap of the slides)."""
    world, labels = straight_street()
    registration = Registration(RegistrationConfig())
    T_ws, T_wt = pose(0.0, 0.0, 1.7, 0.0), pose(60.0, -1.0, 1.7, 175.0)
    sides = [registration.prepare(*scan(world, labels, T)) for T in (T_ws, T_wt)]
    truth = np.linalg.inv(T_wt) @ T_ws
    cfg = registration.config.verification
    overlap, _ = mutual_covisible_overlap(
        np.concatenate([truth[None], slid_poses(truth, 5.0)]),
        *(covisible_side(s, 2.0, cfg) for s in sides),
        0.6,
        1.0,
    )
    assert overlap[0] > 0.97 and overlap[1:].max() > overlap[0] - 0.03


@pytest.mark.parametrize('share, accepted', [(0.25, True), (0.0, False)])
def test_a_rival_both_scans_barely_see_does_not_count(monkeypatch, share, accepted):
    """
    The first pair of the simulated field drive seed 1 at stride 20 (geometric labels).

    The right pose measured 0.978 on 0.39 of the surface, its best slide 0.777 on 0.155, and
    a distinct candidate 0.961 on only 0.036: that rival overlaps on next to nothing, and
    with ``covisibility.accept_rival_share`` (0.25 of the pose's checked share) it does not
    count; without the share (0) it refuses the right pose.
    """
    from mlsemreg_ros.core.stages import covisible_acceptance as stage_module

    def measured(transforms, *_args):
        count = len(transforms)
        overlap = np.array([0.978] + [0.777] * 8 + [0.961] * (count - 9))
        checked = np.array([0.39] + [0.155] * 8 + [0.036] * (count - 9))
        return overlap, checked

    world, labels = facade_street()
    config = RegistrationConfig()
    config.covisibility.accept_rival_share = share
    monkeypatch.setattr(stage_module, 'mutual_covisible_overlap', measured)
    monkeypatch.setattr(stage_module, 'covisible_sides', lambda *_args: (None, None))
    context = judged(world, labels, np.eye(4), [pose(0, 0, 0, 30.0)], config=config)
    diagnostics = context.diagnostics
    assert (context.refusal == '') is accepted, diagnostics
    if accepted:
        assert diagnostics['covisible_accept_rival_overlap'] == 0.0  # none counted
        assert diagnostics['covisible_accept_slide_overlap'] == pytest.approx(0.777)
    else:
        assert 'a distinct candidate' in diagnostics['covisible_accept_refusal']

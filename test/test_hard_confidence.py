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
"""Confidence that knows ambiguity and degeneracy (docs/hard_pairs.md)."""

from __future__ import annotations

from mlsemreg_ros.core.alignment.alignment import align_pair, AlignmentCloud
from mlsemreg_ros.core.config import ConfidenceConfig, RegistrationConfig
from mlsemreg_ros.core.estimation import confidence
from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.pipeline import Registration
import numpy as np
import pytest

LABELS = LabelMap.load()
GRID = 0.25  # m; divides the facade period and the drive, so a slide lines up exactly
PERIOD = 8.0  # m between the window recesses of the facades
DRIVE = 40.0  # m between the two scans


def _grid(x: np.ndarray, other: np.ndarray) -> np.ndarray:
    a, b = np.meshgrid(x, other, indexing='ij')
    return np.column_stack([a.ravel(), b.ravel()])


def _street(poles: bool, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Build a straight street along x: road, sidewalks, facades recessed every 8 m, poles."""
    x = np.arange(-60.0, 100.0 + 1e-9, GRID)
    parts, names = [], []
    road = _grid(x, np.arange(-6.0, 6.0 + 1e-9, GRID))
    parts.append(np.column_stack([road, np.full(len(road), -1.75)]))
    names.append('road')
    for side in (-1.0, 1.0):
        walk = _grid(x, side * np.arange(6.25, 9.0 + 1e-9, GRID))
        parts.append(np.column_stack([walk, np.full(len(walk), -1.6)]))
        names.append('sidewalk')
        wall = _grid(x, np.arange(-1.5, 8.0 + 1e-9, GRID))
        recessed = np.mod(wall[:, 0], PERIOD) < 2.0  # a window recess 2 m of every 8 m
        y = side * (9.5 + 0.5 * recessed)
        parts.append(np.column_stack([wall[:, 0], y, wall[:, 1]]))
        names.append('building')
    if poles:
        rng = np.random.default_rng(seed)
        heights = np.arange(-1.5, 4.0 + 1e-9, GRID)
        ring = 0.15 * np.column_stack(
            [np.cos(np.arange(6) * np.pi / 3), np.sin(np.arange(6) * np.pi / 3)]
        )
        for k, px in enumerate(rng.uniform(-55.0, 95.0, 24)):
            side = 1.0 if k % 2 else -1.0
            xy = np.array([px, side * rng.uniform(6.5, 8.5)]) + ring
            pole = np.column_stack([np.repeat(xy, len(heights), axis=0), np.tile(heights, 6)])
            parts.append(pole)
            names.append('pole' if k % 3 else 'trunk')
    points = np.concatenate(parts)
    labels = np.concatenate(
        [
            np.full(len(p), LABELS.id_of(n), dtype=np.int32)
            for p, n in zip(parts, names, strict=True)
        ]
    )
    return points, labels


def _scan(world: tuple[np.ndarray, np.ndarray], at_x: float) -> tuple[np.ndarray, np.ndarray]:
    points, labels = world
    near = np.abs(points[:, 0] - at_x) <= 45.0
    return points[near] - [at_x, 0.0, 0.0], labels[near]


def _scans(registration: Registration, poles: bool):
    world = _street(poles)
    source, target = (
        registration.prepare(*_scan(world, x), voxelize=False, lazy=True) for x in (DRIVE, 0.0)
    )
    truth = np.eye(4)
    truth[0, 3] = DRIVE  # p_target = p_source + 40 m along the street
    return source, target, truth


@pytest.fixture(scope='module')
def registration() -> Registration:
    return Registration()


def test_a_zero_motion_slide_overlaps_as_much_as_the_truth_on_a_repeated_street(registration):
    source, target, truth = _scans(registration, poles=True)
    at_truth, _ = registration.judge(source, target, truth)
    at_zero, _ = registration.judge(source, target, np.eye(4))
    assert at_zero.overlap >= 0.95 * at_truth.overlap  # the geometry cannot tell them apart
    assert at_zero.label_agreement >= 0.95 * at_truth.label_agreement  # nor the labels
    assert at_truth.distinctive_objects >= 4  # its poles line up ...
    assert at_truth.distinctive_objects >= 0.8 * at_truth.distinctive_in_view
    assert at_zero.distinctive_objects < 0.3 * at_zero.distinctive_in_view  # ... the slide's not


def test_the_poles_decide_for_the_truth_and_the_slide_is_refused_as_ambiguous(registration):
    source, target, truth = _scans(registration, poles=True)
    config = registration.config.confidence
    at_truth, _ = registration.judge(source, target, truth, rivals=np.eye(4)[None])
    assert at_truth.rival_score >= (1 - config.ambiguity_margin) * at_truth.score  # close
    assert at_truth.ambiguity(config) == ''  # ... but decided by its poles
    at_zero, why = registration.judge(source, target, np.eye(4), rivals=truth[None])
    assert 'ambiguous' in why and at_zero.rival in ('rival', 'slide 5 m'), why


def test_without_distinctive_structure_the_truth_is_refused_as_ambiguous(registration):
    source, target, truth = _scans(registration, poles=False)
    evidence, why = registration.judge(source, target, truth, rivals=np.eye(4)[None])
    assert evidence.distinctive_objects == 0
    assert 'ambiguous' in why and 'does not decide' in why, why


def test_an_ambiguous_registration_end_to_end_is_not_accepted(registration):
    """The whole pipeline on the pole-less street: whatever it finds, it does not accept."""
    source, target, _ = _scans(registration, poles=False)
    cheap = Registration(RegistrationConfig().replace({'bev_search.enabled': False}))
    result = cheap.register_scans(source.points, source.labels, target.points, target.labels)
    assert not result.success
    assert result.diagnostics['confidence_rival'] != ''


def test_ambiguity_needs_a_close_rival_and_is_decided_by_distinctive_objects() -> None:
    config = ConfidenceConfig(
        ambiguity_margin=0.3, min_distinctive_objects=2, distinctive_gain=2.0
    )
    base = {'num_inliers': 100, 'correspondences': 2000, 'overlap': 0.4, 'label_agreement': 0.9}
    rivalled = {**base, 'tilt_deg': 0.0, 'score': 0.3, 'rival': 'x'}  # rival 'x' scored
    far = confidence.Evidence(**rivalled, rival_score=0.1)
    assert far.ambiguity(config) == ''  # rival far below
    close = confidence.Evidence(**rivalled, rival_score=0.25)
    assert 'ambiguous: x scores 0.250 against 0.300' in confidence.refusal(close, config, 40)
    objects = {'rival_score': 0.35, 'distinctive_overlap': 0.4}  # a closer rival, objects seen
    decided = confidence.Evidence(
        **rivalled, **objects, distinctive_objects=3, rival_distinctive_overlap=0.1
    )
    assert decided.ambiguity(config) == ''
    one_pole = confidence.Evidence(
        **rivalled, **objects, distinctive_objects=1, rival_distinctive_overlap=0.0
    )
    assert 'does not decide' in one_pole.ambiguity(config)
    assert confidence.Evidence(**base, tilt_deg=0.0).ambiguity(config) == ''  # no rival scored


def _corridor(seed: int, closed: bool) -> np.ndarray:
    """Walls at y = +-3 m, floor and ceiling, 60 m along x (closed: end walls at x = +-8 m)."""
    rng = np.random.default_rng(seed)
    length = 8.0 if closed else 30.0
    x = rng.uniform(-length, length, 12000)
    t = rng.uniform(0.0, 1.0, 12000)
    side = rng.integers(0, 4, 12000)
    y = np.where(side < 2, np.where(side == 0, -3.0, 3.0), -3.0 + 6.0 * t)
    z = np.where(side < 2, -1.0 + 3.0 * t, np.where(side == 2, -1.0, 2.0))
    points = [np.column_stack([x, y, z])]
    if closed:
        u, v = rng.uniform(-3.0, 3.0, 3000), rng.uniform(-1.0, 2.0, 3000)
        points += [np.column_stack([np.full(3000, e), u, v]) for e in (-8.0, 8.0)]
    return np.concatenate(points) + rng.normal(0.0, 0.01, (len(np.concatenate(points)), 3))


@pytest.mark.parametrize('closed', [False, True])
def test_a_corridor_reports_its_weak_direction_along_the_corridor(closed: bool) -> None:
    config = RegistrationConfig().fine
    source, target = (AlignmentCloud.build(_corridor(s, closed), 0.0, 10) for s in (1, 2))
    guess = np.eye(4)
    guess[:3, 3] = [0.3, 0.1, 0.05]
    alignment = align_pair(source, target, guess, config, 'gicp')
    found = confidence.localizability(alignment.hessian, alignment.T_target_source[:3, :3])
    assert found is not None
    limit = ConfidenceConfig().min_localizability
    if closed:
        assert found.ratio > 5 * limit  # the end walls pin it down
    else:
        assert found.ratio < limit and abs(found.weak_direction[0]) > 0.95  # along x
        assert 'degenerate: translation along (+1.00' in confidence.degeneracy_refusal(
            found, ConfidenceConfig(degeneracy='refuse')
        )
        inflated = confidence.inflated_hessian(alignment.hessian, 100.0)
        grown = np.linalg.inv(inflated)[3, 3] / np.linalg.inv(alignment.hessian)[3, 3]
        assert 50.0 < grown < 101.0  # covariance along x, ~100x
        across = np.linalg.inv(inflated)[4, 4] / np.linalg.inv(alignment.hessian)[4, 4]
        assert 0.9 < across < 1.1


def test_a_corridor_registration_says_which_direction_is_weak_and_what_was_done() -> None:
    points = _corridor(1, closed=False)
    labels = np.where(np.abs(points[:, 1]) > 2.9, LABELS.id_of('building'), LABELS.id_of('road'))
    moved = points + np.array([0.4, 0.0, 0.0])
    for action in ('inflate', 'refuse'):
        registration = Registration(
            RegistrationConfig().replace(
                {'confidence.degeneracy': action, 'bev_search.enabled': False}
            )
        )
        result = registration.register_scans(points, labels, moved, labels)
        d = result.diagnostics
        assert d['degeneracy_weak'] and d['degeneracy_action'] == action
        assert d['degeneracy_weak_direction'].startswith(('+1.00', '+0.99'))
        if action == 'refuse':
            assert not result.success

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
The contradiction check and noisy labels (docs/label_noise.md, docs/hard_pairs.md).

Measured after merging the hard-pairs and label-noise work: with 20 % of the source labels
random, the right dev poses put 8-31 distinctive "objects" in the target's view (most of
them made of mislabeled points) and line up 1-6, so the contradiction check refused 5 of
9 right poses of the confidence study. The check now applies only while the labels'
ceiling reaches ``confidence.contradiction_min_ceiling``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from dev_pairs import dev_pair_files
from mlsemreg_ros.core.config import ConfidenceConfig, RegistrationConfig
from mlsemreg_ros.core.estimation import confidence
from mlsemreg_ros.core.metrics import rotation_error_deg, translation_error_m
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.datasets.pairs import load_pair
from noisy_labels import labeled_points_scan
import numpy as np
import pytest

BASE = {
    'num_inliers': 150,
    'correspondences': 5000,
    'overlap': 0.4,
    'label_agreement': 0.7,
    'tilt_deg': 0.5,
}


def _evidence(ceiling: float, lined: int = 3, in_view: int = 13) -> confidence.Evidence:
    return confidence.Evidence(
        **BASE,
        score=0.4,
        distinctive_objects=lined,
        distinctive_in_view=in_view,
        label_ceiling=ceiling,
    )


@pytest.mark.parametrize(
    ('ceiling', 'contradicted'),
    [(0.95, True), (0.90, True), (0.85, True), (0.84, False), (0.76, False), (np.nan, True)],
)
def test_the_contradiction_applies_only_to_labels_clean_enough(ceiling, contradicted) -> None:
    config = ConfidenceConfig(label_rule='fixed')  # the label check itself is not tested here
    reason = confidence.refusal(_evidence(ceiling), config, min_inliers=40)
    assert ('contradicted' in reason) is contradicted, reason


def test_with_clean_labels_a_flip_is_still_contradicted() -> None:
    config = ConfidenceConfig(label_rule='fixed')
    # the 176 deg flip of a 40 m dev pair: 0 of 4 objects in view lined up
    assert 'contradicted' in confidence.refusal(_evidence(0.95, 0, 4), config, 40)
    assert confidence.refusal(_evidence(0.95, 3, 5), config, 40) == ''  # a right pose
    off = ConfidenceConfig(label_rule='fixed', contradiction_min_ceiling=0.0)
    assert 'contradicted' in confidence.refusal(_evidence(0.5), off, 40)  # 0: always


def test_a_dev_pair_with_a_fifth_of_its_labels_random_is_accepted_at_its_true_pose() -> None:
    """Dev pair 000010 (31 objects in view, 6 lined up in the study) with random labels."""
    files = [f for f in dev_pair_files() if f.stem == '000010']
    if not files:
        pytest.skip('dev pair 000010 not found')
    pair = load_pair(files[0])
    rng = np.random.default_rng(3)
    labels = np.array(pair.label_src, dtype=np.int64)
    hit = rng.random(labels.size) < 0.2
    labels[hit] = rng.integers(0, 20, int(hit.sum()))
    config = RegistrationConfig()
    result = Registration(config).register_scans(
        pair.pts_src, labels, pair.pts_dst, pair.label_dst
    )
    T = pair.trans_gt
    assert rotation_error_deg(result.transform[:3, :3], T[:3, :3]) < 5.0
    assert translation_error_m(result.transform[:3, 3], T[:3, 3]) < 0.6
    d = result.diagnostics
    assert d['confidence_label_ceiling'] < config.confidence.contradiction_min_ceiling
    assert d['confidence_distinctive_objects'] < (
        config.confidence.contradicted_fraction * d['confidence_distinctive_in_view']
    )  # the old rule would have refused it
    assert result.success, result.message


@pytest.mark.parametrize(
    ('ceiling', 'refused'), [(0.54, True), (0.59, True), (0.64, False), (np.nan, False)]
)
def test_labels_too_noisy_vouch_for_no_pose(ceiling, refused) -> None:
    # a 42 m slide of a 40 m dev pair with 30 % flipped labels: ceiling 0.54, 14 of 25
    # distinctive objects lined up on mislabeled points, every other rule passed
    config = ConfidenceConfig(label_rule='fixed')
    reason = confidence.refusal(_evidence(ceiling, 14, 25), config, min_inliers=40)
    assert ('too noisy' in reason) is refused, reason
    never = ConfidenceConfig(label_rule='fixed', min_label_ceiling=0.0)
    assert 'too noisy' not in confidence.refusal(_evidence(ceiling, 14, 25), never, 40)


def _pool_of_000008() -> tuple[Any, RegistrationConfig]:
    """Return the two candidates of FPFH dev pair 000008 with 10 % of the labels flipped."""
    from mlsemreg_ros.core.estimation.candidates import CandidatePool
    from mlsemreg_ros.core.results import HypothesisScore, VerificationResult

    right = HypothesisScore(np.eye(4), 0, 60, 0.415, 0.664, 0.275, 'guided')
    off = np.eye(4)
    off[:3, 3] = [4.0, 2.5, 0.0]  # 4.7 m off
    wrong = HypothesisScore(off, 1, 47, 0.322, 0.602, 0.194, 'guided')
    shares, objects, in_view = (
        np.array([0.168, 0.084]),
        np.array([1, 2]),
        np.array([6, 4]),
    )
    pool = CandidatePool.of(
        VerificationResult([right, wrong], 0), lambda _poses: (shares, objects, in_view)
    )
    return pool, RegistrationConfig()


@pytest.mark.parametrize(('trusted', 'chosen'), [(True, 1), (False, 0)])
def test_with_flipped_labels_the_objects_do_not_choose_among_the_candidates(
    trusted, chosen
) -> None:
    """
    Clean labels: 2 of 4 objects lined up win within confidence.decide_margin. Noisy: the score.

    Measured (2026-12-03): the 4.7 m pose lined up 2 of 4 objects by chance and replaced
    the right pose (1 of 6, 1.4 times the score); pair 000008 was then neither right nor
    accepted (FPFH, flip:0.1, distinctive ceiling 0.11, label ceiling 0.809).
    """
    pool, config = _pool_of_000008()
    assert pool.decide(0, config, trusted) == chosen
    assert pool.decide(0, config) == 1  # trusted unless told


@pytest.mark.parametrize(
    ('ceiling', 'distinctive', 'ambiguous', 'contradicted'),
    [
        (0.95, np.nan, False, True),  # unknown distinctive ceiling: the objects count
        (0.95, 0.9, False, True),  # clean labels
        (0.7, 0.9, False, False),  # 30 % confusions: the labels' ceiling stops the contradiction
        (0.8, 0.3, True, False),  # 10 % flips
        (0.95, 0.3, True, False),
    ],
)
def test_with_flipped_labels_the_objects_neither_decide_nor_contradict(
    ceiling, distinctive, ambiguous, contradicted
) -> None:
    config = ConfidenceConfig(label_rule='fixed')
    evidence = confidence.Evidence(
        **BASE,
        score=0.3,
        rival_score=0.28,
        rival='slide 5 m',
        distinctive_objects=3,
        distinctive_in_view=4,
        distinctive_overlap=0.4,
        label_ceiling=ceiling,
        distinctive_ceiling=distinctive,
    )
    assert bool(evidence.ambiguity(config)) is ambiguous
    assert confidence.objects_trusted(distinctive, config) is not ambiguous
    against = dataclasses.replace(evidence, distinctive_objects=0, distinctive_in_view=13)
    assert ('contradicted' in confidence.refusal(against, config, 40)) is contradicted
    off = ConfidenceConfig(min_distinctive_ceiling=0.0)  # 0: the objects always count
    assert confidence.objects_trusted(distinctive, off)


def test_the_distinctive_ceiling_tells_flipped_labels_from_confused_ones() -> None:
    """A street with poles: confusions of road/building leave it, 10 % flips sink it."""
    from mlsemreg_ros.core.estimation.label_model import distinctive_ceiling
    from mlsemreg_ros.core.matching.labels import LabelMap
    from mlsemreg_ros.evaluation.label_noise import LabelNoise

    labels_map = LabelMap.load()
    rng = np.random.default_rng(11)
    ground = np.column_stack(
        [rng.uniform(-20, 20, 20000), rng.uniform(-8, 8, 20000), np.zeros(20000)]
    )
    wall = np.column_stack(
        [rng.uniform(-20, 20, 8000), np.full(8000, 8.0), rng.uniform(0, 6, 8000)]
    )
    poles = np.concatenate(
        [
            np.column_stack([np.full(40, x), np.full(40, 6.0), np.linspace(0, 4, 40)])
            for x in (-12, 0, 12)
        ]
    )
    points = np.vstack([ground, wall, poles])
    ids = {n: labels_map.id_of(n) for n in ('road', 'building', 'pole')}
    labels = np.r_[
        np.full(20000, ids['road']), np.full(8000, ids['building']), np.full(120, ids['pole'])
    ]
    distinctive = np.zeros(labels_map.num_classes, bool)
    distinctive[ids['pole']] = True

    def ceiling(noise: str) -> float:
        scans = []
        for seed in (0, 1):
            noisy = LabelNoise.parse(noise).apply(labels, labels_map, np.random.default_rng(seed))
            scans.append(labeled_points_scan(points, noisy, labels_map.num_classes))
        return distinctive_ceiling(*scans, distinctive, 0.6)

    config = ConfidenceConfig()
    assert ceiling('none') > 0.9
    assert ceiling('confuse:0.5') > 0.9
    assert ceiling('flip:0.1') < config.min_distinctive_ceiling

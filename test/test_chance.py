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
Acceptance by evidence: the chance consensus of the estimator (``core/estimation/chance.py``).

Random pairs: two unrelated rooms sampled on their floor and walls, each keypoint paired
with a random one of the other (no true pairing). SC2-PCR still wins a consensus, and how
large depends on the room: 15-25 of 800 correspondences in a 4 m room, 2-6 in a 30 m one.
A fixed count cannot serve both; the count the chance rule asks for follows the room, so
its false-accept rate on random pairs is 0 in both, and a right pair (15 % true
correspondences) passes in both.
"""

from __future__ import annotations

from mlsemreg_ros.core.estimation import chance
from mlsemreg_ros.core.estimation.confidence import Evidence, refusal
from mlsemreg_ros.core.estimation.config import ConfidenceConfig, EstimatorConfig
from mlsemreg_ros.core.estimation.estimation import estimate
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

CORRESPONDENCES = 800
CHANCE = ConfidenceConfig(count_rule='chance', chance_shuffles=3)


def _room(rng: np.random.Generator, count: int, size: float) -> np.ndarray:
    """Points on the floor and the four 3 m walls of a ``size`` x ``size`` room."""
    wall = rng.integers(0, 5, count)
    points = rng.uniform(0.0, size, (count, 3))
    points[:, 2] = rng.uniform(0.0, 3.0, count)
    points[wall == 0, 2] = 0.0
    points[wall == 1, 0], points[wall == 2, 0] = 0.0, size
    points[wall == 3, 1], points[wall == 4, 1] = 0.0, size
    return points


def _verdict(src: np.ndarray, dst: np.ndarray, config: ConfidenceConfig) -> tuple[int, str]:
    """Return the estimator's winning count and the confidence rule's refusal of it."""
    won = estimate(src, dst, EstimatorConfig()).num_inliers
    draws = chance.chance_consensus(src, dst, EstimatorConfig(), config.chance_shuffles)
    evidence = Evidence(
        won, len(src), 1.0, 1.0, 0.0, chance_inliers=float(draws.max()) if len(draws) else np.nan
    )
    return won, refusal(evidence, config, min_inliers=40)


@pytest.mark.parametrize('size', [4.0, 30.0])
def test_no_random_pair_passes_the_chance_count_and_right_pairs_do(size: float) -> None:
    rng = np.random.default_rng(2)
    rotation = Rotation.from_euler('z', 20.0, degrees=True).as_matrix()
    unrelated, right = [], []
    for _ in range(3):
        src = _room(rng, CORRESPONDENCES, size)
        dst = _room(rng, CORRESPONDENCES, size)
        unrelated.append(_verdict(src, dst, CHANCE))
        true = rng.random(CORRESPONDENCES) < 0.15  # 15 % true pairs, 5 cm of noise
        dst[true] = src[true] @ rotation.T + [1.0, 0.5, 0.0]
        dst[true] += rng.normal(0.0, 0.05, (int(true.sum()), 3))
        right.append(_verdict(src, dst, CHANCE))
    assert all('won by chance' in why for _, why in unrelated), unrelated  # 0 false accepts
    assert all(why == '' for _, why in right), right
    if size < 10.0:  # a small room: chance alone wins more than a big room's right pose needs
        assert min(won for won, _ in unrelated) >= 10


def test_the_chance_draws_follow_the_count_and_the_extent() -> None:
    rng = np.random.default_rng(3)
    small = chance.chance_consensus(
        _room(rng, 800, 4.0), _room(rng, 800, 4.0), EstimatorConfig(), 2
    )
    large = chance.chance_consensus(
        _room(rng, 800, 30.0), _room(rng, 800, 30.0), EstimatorConfig(), 2
    )
    fewer = chance.chance_consensus(
        _room(rng, 200, 4.0), _room(rng, 200, 4.0), EstimatorConfig(), 2
    )
    assert small.min() > 2 * large.max()
    assert small.min() > fewer.max()


def test_the_fixed_count_is_kept_unless_chance_is_asked_for() -> None:
    fixed = ConfidenceConfig()
    evidence = Evidence(30, 1000, 1.0, 1.0, 0.0, chance_inliers=2.0)
    assert 'estimator.min_inliers=40' in refusal(evidence, fixed, 40)
    assert refusal(evidence, CHANCE, 40) == ''  # 30 > max(10, 3 x 2)
    many = Evidence(30, 10000, 1.0, 1.0, 0.0, chance_inliers=2.0)  # ratio 0.003 < 0.005
    assert 'min_inlier_ratio' in refusal(many, fixed, 20)
    assert refusal(many, CHANCE, 20) == ''  # the chance count replaces the ratio too
    assert chance.required_inliers(float('nan'), CHANCE, 40) == 40  # not measured: fixed
    assert chance.required_inliers(3.0, CHANCE, 40) == 10  # the floor
    assert not chance.wanted(250, CHANCE)  # a strong consensus is not measured
    two = np.zeros((2, 3))
    assert len(chance.chance_consensus(two, two, EstimatorConfig(), 3)) == 0

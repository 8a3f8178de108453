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
How large a consensus the estimator finds by chance on this pair (issue 35, part 3).

``estimator.min_inliers`` (40) is one count for every sensor, every correspondence count
and every scan extent. The chance consensus depends on all three: more correspondences,
a larger inlier threshold against a smaller scan, and the estimator's own search over
many hypotheses (SC2-PCR fits each seed's consistent subset and keeps the best) all raise
the consensus a pose wins with no overlap at all. A binomial test of the chosen pose's
inliers against the per-correspondence chance rate ignores that search, and did not
separate right from wrong poses (docs/sensors.md#acceptance-by-evidence).

So the null is measured the way it arises: the estimator runs again on the pair's own
correspondences with the target points re-paired at random (a permutation: the same
points, the same extent and count, the same threshold, no true pairing), and the winning
consensus of each run is a draw of the best chance consensus. The pose's count must exceed
``confidence.chance_margin`` times the largest of ``confidence.chance_shuffles`` draws,
and ``confidence.chance_floor``; this count replaces both ``estimator.min_inliers`` and
``confidence.min_inlier_ratio`` (a count scaled by the correspondences alone). With
``confidence.count_rule: fixed`` (the default) the fixed ``estimator.min_inliers`` applies
instead; the draws are still measured (into the diagnostics, ``confidence_chance_inliers``)
while ``chance_shuffles`` > 0.
"""

from __future__ import annotations

from mlsemreg_ros.core.estimation.config import ConfidenceConfig, EstimatorConfig
import numpy as np

#: Seed of the re-pairings: the same pair gives the same draws.
SEED = 0


def chance_consensus(
    src: np.ndarray, dst: np.ndarray, config: EstimatorConfig, shuffles: int, seed: int = SEED
) -> np.ndarray:
    """
    Return the estimator's winning inlier count on ``shuffles`` random re-pairings.

    ``src``, ``dst`` (K, 3): the pair's correspondences; ``dst`` is permuted, so every
    draw keeps both point sets and breaks every true pairing.
    """
    from mlsemreg_ros.core.estimation.estimation import estimate

    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if len(src) < 3 or shuffles <= 0:
        return np.zeros(0, dtype=np.int64)
    rng = np.random.default_rng(seed)
    counts = []
    for _ in range(shuffles):
        counts.append(estimate(src, dst[rng.permutation(len(dst))], config).num_inliers)
    return np.asarray(counts, dtype=np.int64)


def wanted(num_inliers: int, config: ConfidenceConfig) -> bool:
    """Whether the chance draws are measured for a pose with ``num_inliers``."""
    return config.chance_shuffles > 0 and num_inliers < config.chance_max_inliers


def required_inliers(chance: float, config: ConfidenceConfig, min_inliers: int) -> float:
    """
    Return the inliers a pose needs: ``estimator.min_inliers`` or the chance rule's count.

    ``chance``: the largest chance draw (NaN: not measured). Under
    ``confidence.count_rule: chance`` a measured draw gives
    ``max(chance_floor, chance_margin * chance)``; a pose with at least
    ``confidence.chance_max_inliers`` was not measured and passes.
    """
    if config.count_rule != 'chance':
        return float(min_inliers)
    if not np.isfinite(chance):
        return float(min(min_inliers, config.chance_max_inliers))
    return max(float(config.chance_floor), config.chance_margin * float(chance))

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

"""The registration's stage list: the loop times each stage and judges the candidates it adds."""

from __future__ import annotations

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.estimation.verification import score_hypotheses
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.results import VerificationResult
from mlsemreg_ros.core.stages.confidence import ConfidenceStage
from mlsemreg_ros.core.stages.context import RegistrationContext
from mlsemreg_ros.datasets.synthetic_scene import motion, synthetic_pair
import numpy as np
import pytest


@pytest.fixture(scope='module')
def prepared():
    pair = synthetic_pair(seed=0)
    registration = Registration(RegistrationConfig().replace({'keypoints.count': 1000}))
    source, target = registration.prepare_scans(
        {'points': pair.pts_src, 'labels': pair.label_src},
        {'points': pair.pts_dst, 'labels': pair.label_dst},
    )
    return registration, source, target, pair.trans_gt


class Proposal:
    """A candidate source (as the recipe in docs/extending.md): proposes one given pose."""

    name = 'proposal'

    def __init__(self, T_target_source: np.ndarray) -> None:
        self.T_target_source = T_target_source

    def wanted(self, context: RegistrationContext) -> bool:
        return True

    def run(self, context: RegistrationContext) -> VerificationResult:
        cfg = context.config
        return score_hypotheses(
            self.T_target_source[None],
            np.zeros(1, dtype=np.int64),
            context.source_points,
            context.target_points,
            context.source,
            context.target,
            cfg.verification,
            cfg.estimator,
            context.scoring.compatibility,
            origin='proposal',
        )


class Probe:
    """Record what the context holds when this stage's turn comes; never wanted."""

    name = 'probe'

    def __init__(self) -> None:
        self.origins: list[str] = []
        self.chosen = ''

    def wanted(self, context: RegistrationContext) -> bool:
        self.origins = [h.origin for h in context.pool.hypotheses]
        self.chosen = context.pool.origin(context.chosen)
        return False

    def run(self, context: RegistrationContext) -> None:
        raise AssertionError('a stage that is not wanted never runs')


def test_the_default_stages_run_in_order_and_each_is_timed_by_the_loop(prepared) -> None:
    registration, source, target, truth = prepared
    names = [stage.name for stage in registration.stages]
    assert names == [
        'label_quality',
        'gm_mm',
        'estimator',
        'verification',
        'confidence',
        'objects',
        'bev_search',
        'early_accept',
        'bev_search_swapped',
        'early_accept',
        'far_search',
        'early_accept',
        'guided',
        'early_accept',
        'early_refuse',
        'full_graph',
        'polish',
        'covisibility',
        'unlabeled_fallback',
        'level_check',
        'fine',
        'near_miss',
        'covisible_accept',
        'unlabeled_rerun',
    ]
    result = registration.register(source, target)
    assert result.success, result.message
    assert {
        'label_quality_ms',
        'gm_mm_ms',
        'estimator_ms',
        'verification_ms',
        'confidence_ms',
        'fine_ms',
        'near_miss_ms',
    } <= set(result.timings_ms)
    assert 'bev_search_ms' not in result.timings_ms  # an accepted, strong pose: not wanted
    assert np.linalg.norm(result.transform[:3, 3] - truth[:3, 3]) < 0.3


@pytest.mark.parametrize(('offset', 'chosen'), [(8.0, 'estimator'), (0.0, None)])
def test_a_stage_added_to_the_list_is_timed_and_its_candidates_face_the_confidence_rule(
    prepared, offset, chosen
) -> None:
    registration, source, target, truth = prepared
    registration.stages = registration.stages.copy()
    at = [type(s) for s in registration.stages].index(ConfidenceStage) + 1
    probe = Probe()
    registration.stages[at:at] = [Proposal(motion(0.0, (offset, 0.0, 0.0)) @ truth), probe]
    try:
        result = registration.register(source, target)
    finally:
        registration.stages = [
            s for s in registration.stages if s.name not in ('proposal', 'probe')
        ]
    assert 'proposal_ms' in result.timings_ms and 'probe_ms' not in result.timings_ms
    assert 'proposal' in probe.origins  # joined the pool
    # a pose 8 m off loses against the estimator's; the truth itself may win or tie
    assert probe.chosen == chosen if chosen else probe.chosen in ('estimator', 'proposal')
    assert result.success

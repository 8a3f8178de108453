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
One way to accept a refined pose: ``Decision.of_alignment`` and ``Decision.rescued``.

Known answers on a hand-made alignment (core/odometry/steps.py): the pose, the frame
covariance in the current frame's axes scaled by ``odometry.covariance_scale``, the inlier
fraction; a rescue keeps the refusal's result and timings and adds its candidate.
"""

from mlsemreg_ros.core.alignment.alignment import Alignment
from mlsemreg_ros.core.odometry.steps import Decision
from mlsemreg_ros.core.odometry.trust import Candidate
import numpy as np
from scipy.spatial.transform import Rotation


def _alignment() -> Alignment:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler('z', 30, degrees=True).as_matrix()
    pose[:3, 3] = [1.0, 2.0, 0.0]
    return Alignment(
        T_target_source=pose,
        T_initial=np.eye(4),
        converged=True,
        iterations=5,
        num_inliers=300,
        num_points=400,
        error=12.0,
        hessian=np.diag([400.0, 400.0, 100.0, 50.0, 50.0, 200.0]),
    )


def test_of_alignment_known_answer():
    alignment = _alignment()
    decision = Decision.of_alignment('global', 'note', alignment, 2.0)
    assert decision.accepted and decision.source == 'global' and decision.reason == 'note'
    np.testing.assert_array_equal(decision.pose, alignment.T_target_source)
    np.testing.assert_allclose(decision.frame_covariance, alignment.covariance(2.0, axes='source'))
    np.testing.assert_allclose(
        decision.frame_covariance, 2.0 * alignment.covariance(1.0, axes='source')
    )
    assert decision.inlier_fraction == 0.75
    assert decision.candidates == [] and decision.timings_ms == {}
    assert decision.result is None and not decision.confirm_weak


def test_rescued_keeps_the_refusal_and_adds_the_candidate():
    alignment = _alignment()
    refused_candidate = Candidate('prediction', np.eye(4), alignment, 'moved too far')
    timings = {'fine_prediction_ms': 3.0}
    refused = Decision(
        source='',
        reason='prediction: moved too far',
        candidates=[refused_candidate],
        timings_ms=timings,
    )
    assert not refused.accepted
    rescuer = Candidate('global', np.eye(4), alignment, '')
    decision = refused.rescued(rescuer, 'confirmed by the gyro', 1.0)
    assert decision.accepted and decision.source == 'global'
    assert decision.reason == 'prediction: moved too far; confirmed by the gyro'
    assert decision.candidates == [refused_candidate, rescuer]
    assert decision.timings_ms is timings  # later stages add their times to the same dict
    assert refused.candidates == [refused_candidate]  # the refusal itself is unchanged
    np.testing.assert_array_equal(decision.pose, alignment.T_target_source)


def _held(fraction: float) -> Alignment:
    alignment = _alignment()
    return Alignment(
        T_target_source=alignment.T_target_source,
        T_initial=alignment.T_initial,
        converged=True,
        iterations=5,
        num_inliers=round(400 * fraction),
        num_points=400,
        error=12.0,
        hessian=alignment.hessian,
    )


def test_a_still_start_the_global_estimate_does_not_confirm_must_hold_as_tracked():
    from types import SimpleNamespace

    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.odometry.decision import decide
    from mlsemreg_ros.core.odometry.global_registration import GlobalEstimate

    cfg = RegistrationConfig()
    failed = GlobalEstimate(SimpleNamespace(message='ambiguous'), None)  # the result's reason

    def refine(T):  # the global estimate failed: never called
        raise AssertionError('no global pose to refine')

    # a room's walls and floor hold a third of another room's scan: a guess, not a pose
    weak = Candidate('prediction', np.eye(4), _held(0.34), '', still=True)
    refused = decide(failed, weak, refine, cfg)
    assert not refused.accepted and 'a still start (no motion known)' in refused.reason
    assert 'tracking_min_inlier_fraction' in refused.reason
    # as much as a tracked scan keeps: accepted, as before
    held = Candidate('prediction', np.eye(4), _held(0.8), '', still=True)
    assert decide(failed, held, refine, cfg).accepted
    # a motion model's prediction keeps the ordinary rules (0.34 > min_inlier_fraction)
    predicted = Candidate('prediction', np.eye(4), _held(0.34), '')
    assert decide(failed, predicted, refine, cfg).accepted

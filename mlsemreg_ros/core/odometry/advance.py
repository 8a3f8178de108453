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
The odometry's state moves: start on a keyframe, or accept a decided scan.

:func:`accept` aligns the sweep (tracking.py), moves the pose and the motion model,
calibrates the frame's covariance (docs/covariance.md), inserts the scan into the local map
and moves the keyframe (local_map.py), and returns the step (steps.py). :func:`start`
makes a scan the keyframe and the first scan of a new map (the first scan, a
re-initialisation).
"""

from __future__ import annotations

from typing import Any, TYPE_CHECKING

from mlsemreg_ros.core.alignment.covariance import (
    calibrated_covariance,
    keyframe_term,
    motion_size,
)
from mlsemreg_ros.core.deferred import stored
from mlsemreg_ros.core.odometry.local_map import insert_accepted, Keyframe
from mlsemreg_ros.core.odometry.preprocess import PreprocessedScan
from mlsemreg_ros.core.odometry.start_twist import inflated_covariance
from mlsemreg_ros.core.odometry.steps import accepted_step, Decision, OdometryStep
from mlsemreg_ros.core.odometry.sweep_ahead import Memo
from mlsemreg_ros.core.rigid import invert_transform
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.odometry.odometry import Odometry


def accept_scan(
    odometry: Odometry, index: int, stamp_ns: int, raw: PreprocessedScan, chosen: Decision
) -> OdometryStep:
    """Align the sweep, move the pose, feed the map, move the keyframe; the step."""
    keyframe, start, odometry._start_scan = odometry.keyframe, odometry._start_scan, None
    ahead = None  # the covariance of the likely pose while its sweep alignment runs
    if chosen.pose is not None and odometry.tracker.ahead.started_for(raw):
        early = _covariance_inputs(odometry, chosen, keyframe, chosen.pose, stamp_ns)
        ahead = Memo(calibrated_covariance, *early)
    raw, pose, sweep_twist = odometry.tracker.align_accepted(
        chosen,
        raw,
        start,
        stamp_ns,
        keyframe,
        odometry.preprocessor,
        odometry.motion_model,
        odometry.config,
    )
    if pose is None:  # the sweep alignment did not confirm a weak pose (second_look.py)
        odometry._start_scan = start
        result = chosen.result
        relative = result.transform if result is not None else None
        return odometry._rejected(index, stamp_ns, raw.scan, chosen.reason, result, relative)
    if sweep_twist is not None:
        odometry._sweep_twist = (sweep_twist, stamp_ns)
    current, relative = raw.scan, invert_transform(keyframe.pose) @ pose
    inputs = _covariance_inputs(odometry, chosen, keyframe, pose, stamp_ns)  # covariance.md
    if ahead is not None:  # computed beside the sweep alignment: the same inputs, its result
        chosen.frame_covariance = ahead(*inputs)
    else:
        chosen.frame_covariance = calibrated_covariance(*inputs[0], **inputs[1])
    disputed = odometry.tracker.start_dispute  # the first scan's unknown twist
    if disputed is not None:
        chosen.frame_covariance = inflated_covariance(chosen.frame_covariance, disputed)
    own_covariance = chosen.frame_covariance  # against the map: what a keyframe passes on
    chosen.frame_covariance = own_covariance + keyframe_term(
        keyframe.frame_covariance,
        relative,
        chosen.residual_variance,
        keyframe.residual_variance,
        odometry.config.covariance,
    )
    last, odometry._last_accepted = odometry._last_accepted, (pose.copy(), stamp_ns)
    odometry._accepted.append(odometry._last_accepted)
    odometry.pose = pose.copy()
    odometry.motion_model.update(pose, stamp_ns)
    learn_labels = getattr(odometry.registration, 'learn_labels', None)  # stand-ins lack it
    if learn_labels is not None:
        learn_labels(relative, current, keyframe.prepared)  # confidence.label_model adaptive
    odometry.keyframe, voxels = insert_accepted(
        odometry.map, odometry.config, keyframe, relative, index, stamp_ns, raw, pose
    )
    step = accepted_step(
        index, stamp_ns, pose, relative, chosen, raw, keyframe, last, odometry.covariance, voxels
    )
    odometry.covariance = step.covariance.copy()
    odometry._last_frame_covariance = chosen.frame_covariance
    step.new_keyframe = odometry.keyframe is not keyframe
    if step.new_keyframe:
        odometry.past_keyframes.remember(keyframe)
        odometry.keyframe.frame_covariance = own_covariance
        odometry.keyframe.residual_variance = chosen.residual_variance
    odometry.tracker.prefetch_gaussians(raw, odometry.config)  # for the next scan
    return step


def _covariance_inputs(
    odometry: Odometry, chosen: Decision, keyframe: Keyframe, pose: np.ndarray, stamp_ns: int
) -> tuple[tuple[Any, ...], dict[str, Any]]:
    """Return the arguments of the accepted frame's ``calibrated_covariance`` at ``pose``."""
    relative = invert_transform(keyframe.pose) @ pose
    predicted = [  # a still start predicts no motion: no correction from it
        c.T_initial for c in chosen.candidates if c.name == 'prediction' and not c.still
    ]
    moved = invert_transform(predicted[0]) @ pose if predicted else np.eye(4)
    last = odometry._last_accepted
    args = (chosen.frame_covariance, 1.0, odometry.config.covariance, *motion_size(relative))
    return args, {
        'correction': motion_size(moved),
        'horizon_s': (stamp_ns - last[1]) * 1e-9 if last else 0.0,
        'correction_direction': moved[:3, 3],
        'bend_m': chosen.sweep_bend_m,
        'residual_variance': chosen.residual_variance,
    }


def start_keyframe(
    odometry: Odometry, index: int, stamp_ns: int, raw: PreprocessedScan, pose: np.ndarray
) -> None:
    """Make ``raw`` the keyframe at ``pose`` and the first scan of a new map."""
    labels = stored(raw, 'labels')
    odometry.keyframe = Keyframe(index, stamp_ns, raw.points, labels, raw.scan, pose.copy())
    odometry.past_keyframes.clear()  # their map is gone
    odometry.map.clear()
    odometry.map.insert_scan(raw.scan, pose)
    odometry.motion_model.reset()
    odometry.motion_model.update(pose, stamp_ns)
    odometry._last_accepted = (pose.copy(), stamp_ns)
    odometry._accepted.clear()
    odometry._accepted.append(odometry._last_accepted)
    odometry.tracker.restart()
    odometry._failures = 0
    odometry._start_scan = (raw, pose.copy(), stamp_ns)
    odometry._sweep_twist = None

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
The global registration of a scan onto the keyframe (what makes the odometry robust).

``Registration.register(current, keyframe, refine=False)`` runs ML-SemReg -> SC2-PCR ->
hypothesis verification -> BEV search -> confidence (``core/pipeline.py``); the fine
alignment is the odometry's own, against its map. This component composes the result
with the keyframe pose: ``T_odom_current = T_odom_keyframe @ T_keyframe_current``.

Onto the drive's **first keyframe** the registration refines the pair itself
(``refine=True``, as ``eval-pairs`` does). The odometry's map is then that one scan, so the
pair's fine alignment is the refinement the map would give, and with it the refused path's
last stages can judge the pose (the covisible acceptance, stage 9, needs a refined pose).
Without it a first pair short of ``estimator.min_inliers`` is refused, the keyframe stays
at the first scan and every later scan is farther from it: the simulated field drive seed 1
at stride 20 with geometric labels refused all 9 scans (its first pair, 18 m apart, has 26
inliers of 40); with it, 9 of 9 right, 0 wrong (docs/labels.md). Later keyframes keep
``refine=False``: their map holds more than the keyframe, and refining every global
registration would run the refused path's end stages on every refused one.
``odometry.refine_first_keyframe`` (on) turns it off.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mlsemreg_ros.core.odometry.local_map import Keyframe
from mlsemreg_ros.core.results import PreparedScan, RegistrationResult
import numpy as np

#: The frame counter (``Keyframe.index``) of the first keyframe after a start or ``reset()``;
#: a re-initialisation after lost scans keeps its own counter and is not refined here.
FIRST_KEYFRAME = 0


@dataclass
class GlobalEstimate:
    """One global registration and the pose it implies."""

    result: RegistrationResult  # transform: T_keyframe_current
    T_odom_current: np.ndarray | None  # pose_keyframe @ transform; None: not usable

    @property
    def usable(self) -> bool:
        """Whether the registration succeeded with a finite transform."""
        return self.T_odom_current is not None


class GlobalRegistration:
    """Registers the current scan onto the keyframe."""

    def __init__(self, registration: Any) -> None:
        """Register with ``registration`` (a :class:`~mlsemreg_ros.core.pipeline.Registration`)."""
        self.registration = registration

    def __call__(self, current: PreparedScan, keyframe: Keyframe) -> GlobalEstimate:
        """Return the estimate of ``current`` onto ``keyframe`` (completes both lazily)."""
        first = keyframe.index == FIRST_KEYFRAME  # the pair refines itself (module docstring)
        first = first and self.registration.config.odometry.refine_first_keyframe
        result = self.registration.register(current, keyframe.prepared, refine=first)
        usable = bool(result.success) and bool(np.all(np.isfinite(result.transform)))
        return GlobalEstimate(result, keyframe.pose @ result.transform if usable else None)

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
After a run of refusals: relocalization against the keyframes the odometry left behind.

The odometry recovers from one refused scan by itself: the next scan's prediction is
extrapolated over the gap in the stamps (``motion_model.py``), refined against the local
map, and the scan is registered onto the keyframe (``tracking.py``). Only after
``keyframe.max_failures`` refusals in a row does it give up on the keyframe; then
:meth:`PastKeyframes.relocalize` registers the scan onto the last
``keyframe.relocalization_keyframes`` keyframes (newest first) and refines each estimate
against the local map, judged by the same trust rules (``trust.py``). Only if none is
accepted does the odometry re-initialise at the last accepted pose, with the jump flagged
(``source: reinitialized``, covariance inflated).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
import time
from typing import TYPE_CHECKING

from mlsemreg_ros.core.odometry.global_registration import GlobalEstimate
from mlsemreg_ros.core.odometry.local_map import Keyframe
from mlsemreg_ros.core.odometry.steps import Decision
from mlsemreg_ros.core.results import PreparedScan

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.odometry.tracking import Tracker


class PastKeyframes:
    """The keyframes the odometry replaced, newest last: its keyframe map to relocalize in."""

    def __init__(self, size: int) -> None:
        """Keep at most ``size`` keyframes (``keyframe.relocalization_keyframes``)."""
        self._keyframes: deque[Keyframe] = deque(maxlen=max(size, 0))

    def __len__(self) -> int:
        return len(self._keyframes)

    def resize(self, size: int) -> None:
        """Keep at most ``size`` keyframes from now on (the newest are kept)."""
        if size != self._keyframes.maxlen:
            self._keyframes = deque(self._keyframes, maxlen=max(size, 0))

    def clear(self) -> None:
        """Forget every keyframe (a reset, a new map)."""
        self._keyframes.clear()

    def newest_first(self) -> list[Keyframe]:
        """Return the kept keyframes, newest first."""
        return list(reversed(self._keyframes))

    def remember(self, keyframe: Keyframe | None) -> None:
        """Keep ``keyframe``, which is being replaced."""
        if keyframe is not None and self._keyframes.maxlen:
            self._keyframes.append(keyframe)

    def relocalize(
        self,
        current: PreparedScan,
        tracker: Tracker,
        register: Callable[[PreparedScan, Keyframe], GlobalEstimate],
        cfg: RegistrationConfig,
        timings: dict[str, float],
    ) -> tuple[Decision | None, str]:
        """
        Register ``current`` onto the past keyframes, newest first; the first trusted pose.

        Each successful global registration is refined against the local map and judged
        by ``tracker.trust``. Returns the decision (None: no keyframe gave a trusted pose)
        and what each keyframe said.
        """
        tic = time.perf_counter()
        said = []
        try:
            for keyframe in reversed(self._keyframes):
                estimate = register(current, keyframe)
                if not estimate.usable:
                    message = estimate.result.message or 'failed'
                    said.append(f'keyframe {keyframe.index}: {message}')
                    continue
                candidate = tracker.candidate('relocalized', estimate.T_odom_current, current, cfg)
                if not candidate.acceptable:
                    said.append(f'keyframe {keyframe.index}: {candidate.refusal}')
                    continue
                return Decision.of_alignment(
                    'relocalized',
                    f'relocalized onto the past keyframe {keyframe.index}',
                    candidate.alignment,
                    cfg.odometry.covariance_scale,
                    result=estimate.result,
                    candidates=[candidate],
                ), '; '.join(said)
            return None, '; '.join(said) or 'no past keyframe'
        finally:
            timings['relocalization_ms'] = 1e3 * (time.perf_counter() - tic)

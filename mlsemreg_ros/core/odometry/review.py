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
The decision reviewed: what may overrule the tracked or registered pose of a scan.

In order, each reading the decision before it (``Odometry.process``'s decide step):

- prior_guard.py: a motion prior that disagrees with the scan: the scan again without it;
- deskew_guard.py: a deskew that made the alignment worse: the scan again without it;
- gyro_rescue.py: a refused global pose the gyro confirms, when nothing predicted the scan;
- sweep_starts.py: a refused scan aligned again from other starts of its sweep;
- sparse_deskew.py: a narrow view refused on a sparse stream: again without the turn;
- seeded_search.py: a scan refused after a gap matched onto the keyframe around its
  prediction, accepted on its overlap where both scans see;
- map_search.py: a narrow view refused on a sparse stream matched onto the map's scans
  (the keyframe and the past keyframes) around its prediction, turned up to 40 deg;
- start_search.py: a narrow view's refused scan with no motion known, matched onto the
  keyframe from seeds along its view axis, judged as the seeded search;
- ring_start_search.py: a full ring's refused scan with no motion known, matched onto the
  keyframe from seeds along its forward axis (+x), judged by stage 9's bar;
- failures.py: at the ``keyframe.max_failures``-th rejection in a row, relocalization
  onto the past keyframes (recovery.py).
"""

from __future__ import annotations

from typing import Any, TYPE_CHECKING

from mlsemreg_ros.core.odometry.deskew_guard import guard_deskew
from mlsemreg_ros.core.odometry.failures import relocalize
from mlsemreg_ros.core.odometry.gyro_rescue import rescue_by_gyro
from mlsemreg_ros.core.odometry.map_search import search_local_map
from mlsemreg_ros.core.odometry.motion_model import Prediction
from mlsemreg_ros.core.odometry.preprocess import PreprocessedScan
from mlsemreg_ros.core.odometry.prior_guard import guard_prior
from mlsemreg_ros.core.odometry.ring_start_search import search_along_forward
from mlsemreg_ros.core.odometry.seeded_search import search_around_prediction
from mlsemreg_ros.core.odometry.sparse_deskew import retry_turn_stopped
from mlsemreg_ros.core.odometry.start_search import search_along_view
from mlsemreg_ros.core.odometry.steps import Decision
from mlsemreg_ros.core.odometry.sweep_starts import retry_refused

if TYPE_CHECKING:
    from mlsemreg_ros.core.odometry.odometry import Odometry


def review(
    odometry: Odometry,
    given: tuple[Any, ...],
    prediction: Prediction | None,
    raw: PreprocessedScan,
    chosen: Decision,
    timings: dict[str, float],
) -> tuple[PreprocessedScan, Decision, str, str]:
    """
    Return the scan, the decision after the checks, and the prior's and deskew's refusals.

    ``given`` is what ``Odometry.process`` was given: (points, labels, point_times, stamp).
    """
    raw, chosen, prior_refusal = guard_prior(  # core/odometry/prior_guard.py
        odometry, given, prediction, raw, chosen, timings
    )
    raw, chosen, deskew_refusal = guard_deskew(  # core/odometry/deskew_guard.py
        odometry, given, prediction, raw, chosen, timings
    )
    chosen = rescue_by_gyro(odometry, given[3], prediction, raw, chosen, timings)  # gyro_rescue
    raw, chosen = retry_refused(odometry, given, prediction, raw, chosen, timings)  # sweep_starts
    raw, chosen = retry_turn_stopped(
        odometry, given, prediction, raw, chosen, timings
    )  # sparse_deskew
    chosen = search_around_prediction(odometry, prediction, raw, chosen, timings)  # after a gap
    chosen = search_local_map(odometry, prediction, raw, chosen, timings)  # map_search.py
    chosen = search_along_view(
        odometry, given[3], prediction, raw, chosen, timings
    )  # start_search
    chosen = search_along_forward(
        odometry, given[3], prediction, raw, chosen, timings
    )  # ring_start_search
    chosen = relocalize(odometry, raw, chosen, timings)  # core/odometry/recovery.py
    return raw, chosen, prior_refusal, deskew_refusal

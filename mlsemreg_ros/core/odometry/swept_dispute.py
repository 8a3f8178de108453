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
A near-miss dispute judged again once the sweep is deskewed again (issues 29 and 35).

The odometry's near-miss check (``second_look.py``) judges a pose on the scan as it was
deskewed before the pose was known: by the motion model's twist, or not at all on the
first pair. A sweep bent by a wrong twist can show two basins that are both artefacts of
the bend: on the HDL-64 field drive (seed 7, stride 5, geometric labels) the first pair's
refined pose and its rival lay 0.62 and 0.65 m from the truth, and the pose the start's
deskew and the sweep alignment then made from the refined one was 0.02 m off; on the HDL-32
drive a tracked scan's basins lay 0.55 and 0.64 m off, the swept pose 0.08 m. Neither
basin's residual, inlier share or distance to the prediction named the nearer one in every
dispute found (docs/confidence.md, session 19).

So with ``near_miss.recheck_swept``, a scan refused for a dispute that no later path
accepts (``review.py``: the refused scan's other sweep starts, the seeded search,
relocalization) gets one more chance: its disputed pose goes on to the start's deskew and
the sweep alignment (``Tracker.align_accepted``), and the basins are judged again at the pose
they give, on the scan deskewed again. It is accepted only when no rival basin disputes it
there; otherwise it stays refused, and the map, keyframe and history are as they were. A
scan the sweep alignment did not deskew again stays refused (the same scan, the same
dispute). A scan a later path accepts is left as it is: on a field drive at stride 30 the
recheck kept a disputed pose 0.55 m off that the refused scan, deskewed again by the refused
global pose's twist (``sweep_starts.py``), placed 0.21 m off.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

from mlsemreg_ros.core.odometry.preprocess import PreprocessedScan
from mlsemreg_ros.core.odometry.second_look import basins
from mlsemreg_ros.core.odometry.steps import Decision
from mlsemreg_ros.core.results import PreparedScan
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.odometry.tracking import Tracker


def judged_again(
    disputed: Decision | None,
    disputed_scan: PreprocessedScan,
    raw: PreprocessedScan,
    chosen: Decision,
) -> tuple[PreprocessedScan, Decision]:
    """
    Return the scan and decision to apply: ``chosen``, or the disputed pose when none accepts.

    ``disputed``: the pose the near-miss check refused (``Tracker.disputed``, None: none),
    ``disputed_scan`` the scan it was refined on; ``raw`` and ``chosen`` what the odometry's
    review decided. The disputed pose keeps the refusal's reason; ``Tracker.align_accepted``
    judges it again (:func:`swept_refusal`) and refuses it if its basins still dispute it.
    """
    if chosen.accepted or disputed is None:
        return raw, chosen
    return disputed_scan, dataclasses.replace(
        disputed, reason=chosen.reason, timings_ms=chosen.timings_ms
    )


def swept_refusal(
    tracker: Tracker,
    pose: np.ndarray,
    scan: PreparedScan,
    deskewed_again: bool,
    cfg: RegistrationConfig,
) -> str:
    """
    Why a disputed pose stays refused after the sweep's deskew ('' when it is accepted).

    ``pose`` and ``scan``: the pose and scan after the start's deskew and the sweep
    alignment; ``deskewed_again``: whether either deskewed the scan again (else the dispute
    stands as it was).
    """
    if not deskewed_again:
        return 'still refused: the sweep was not deskewed again'
    candidate = tracker.candidate('swept', pose, scan, cfg)
    if not candidate.acceptable:
        return f'still refused after the sweep was deskewed again: {candidate.refusal}'
    verdict = basins(tracker, candidate, scan, cfg)
    if verdict.refusal:
        return f'still refused after the sweep was deskewed again: {verdict.refusal}'
    return ''

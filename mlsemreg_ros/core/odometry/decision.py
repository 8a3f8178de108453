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
The choice between candidates of the current pose (never a silent jump).

:func:`decide` after a global registration; :func:`chain` with ``fine.method: off``
(the scan-to-keyframe chain). A candidate is acceptable only if its fine alignment kept
``odometry.min_inlier_fraction`` of the scan as map inliers, at least
``odometry.min_relative_inlier_fraction`` of the median fraction of the last accepted
frames, and moved its initial guess by at most ``odometry.max_correction_*``
(``core/alignment/fine_alignment.py``). Without an acceptable candidate the frame is rejected.
On a full ring a still start (no motion known yet, ``odometry.still_start``) that the global
estimate does not confirm is acceptable only as a tracked scan would be
(:func:`unconfirmed_still`).
"""

from __future__ import annotations

from collections.abc import Callable
import dataclasses
import time

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry.config import OdometryConfig
from mlsemreg_ros.core.odometry.global_registration import GlobalEstimate
from mlsemreg_ros.core.odometry.steps import Decision, sparse_inlier_covariance
from mlsemreg_ros.core.odometry.trust import Candidate
from mlsemreg_ros.core.poses import within_bounds
import numpy as np


def decide(
    estimate: GlobalEstimate,
    predicted: Candidate | None,
    refine: Callable[[np.ndarray], Candidate],
    cfg: RegistrationConfig,
    full_ring: bool = True,
) -> Decision:
    """
    Accept one candidate or reject the frame.

    1. The global estimate counts when the registration succeeded (enough sparse
       inliers) and is finite: ``T_global = pose_keyframe @ T_keyframe_current``.
    2. If the refined prediction is acceptable and within ``odometry.agreement_*`` of
       ``T_global``, it is accepted (source ``prediction+global``): both agree, and
       the second alignment is not needed.
    3. Otherwise ``T_global`` is refined too (``refine``), and among the acceptable
       candidates the one with the most alignment inliers wins (a tie goes to the global
       one): a wrong global estimate (the mirror pose of a street) loses against the
       prediction, a wrong prediction (a jump in speed) against the global estimate.
    4. No acceptable candidate: the frame is rejected; pose, keyframe and map stay.

    On a ``full_ring`` a still start outside step 2 must hold as a tracked scan
    (:func:`unconfirmed_still`); a narrow view's still start keeps far less of its
    non-repetitive pattern when right (``core/odometry/narrow_view.py``).
    """
    odometry, result, T_global = cfg.odometry, estimate.result, estimate.T_odom_current
    timings: dict[str, float] = {}
    candidates = [predicted] if predicted is not None else []
    chosen: Candidate | None = None
    source = ''
    notes = []
    if T_global is None:
        notes.append(f'global registration failed ({result.message or "non-finite"})')
    if (
        T_global is not None
        and predicted is not None
        and predicted.acceptable
        and within_bounds(
            predicted.alignment.T_target_source,
            T_global,
            odometry.agreement_translation,
            odometry.agreement_rotation,
        )
    ):
        chosen, source = predicted, 'prediction+global'
    else:
        if full_ring:
            candidates = [unconfirmed_still(c, odometry) for c in candidates]
        if T_global is not None:
            tic = time.perf_counter()
            candidates.append(refine(T_global))
            timings['fine_global_ms'] = 1e3 * (time.perf_counter() - tic)
        acceptable = [c for c in candidates if c.acceptable]
        if acceptable:
            # most inliers wins; a tie goes to the global candidate (listed last)
            chosen = max(reversed(acceptable), key=lambda c: c.alignment.num_inliers)
            source = chosen.name
            if T_global is not None and chosen.name == 'prediction':
                notes.append('the global estimate disagrees with the local map')
    if chosen is None:
        reasons = [f'{c.name}: {c.refusal}' for c in candidates]
        return Decision(
            source='',
            reason='; '.join(notes + reasons) or 'no candidate',
            result=result,
            relative=result.transform if estimate.usable else None,
            candidates=candidates,
            timings_ms=timings,
        )
    return Decision.of_alignment(
        source,
        '; '.join(notes),
        chosen.alignment,
        odometry.covariance_scale,
        result=result,
        candidates=candidates,
        timings_ms=timings,
    )


def unconfirmed_still(candidate: Candidate, odometry: OdometryConfig) -> Candidate:
    """
    Return ``candidate``, refused if it is a still start weaker than a tracked scan.

    A still start is the last pose itself, no motion known: a guess, not a model. Without
    the global estimate's agreement it stands only where a scan tracked alone would: it
    keeps at least ``odometry.tracking_min_inlier_fraction`` of the scan. Any room's walls
    and floor hold a third of a scan from another room (two real indoor scans of different
    sensors, 0.34 of the scan: a wrong pose published before this rule, docs/sensors.md).
    """
    fraction = candidate.alignment.inlier_fraction
    if not candidate.still or candidate.refusal:
        return candidate
    if fraction >= odometry.tracking_min_inlier_fraction:
        return candidate
    return dataclasses.replace(
        candidate,
        refusal=(
            f'a still start (no motion known) unconfirmed by the global estimate kept '
            f'{fraction:.2f} of the scan < odometry.tracking_min_inlier_fraction='
            f'{odometry.tracking_min_inlier_fraction:g}'
        ),
    )


def chain(estimate: GlobalEstimate, cfg: RegistrationConfig) -> Decision:
    """``fine.method: off``: the pose is ``pose_keyframe @ T`` of a successful registration."""
    result = estimate.result
    if not estimate.usable:
        reason = result.message or 'non-finite transform'
        return Decision(source='', reason=reason, result=result, relative=result.transform)
    return Decision(
        source='global',
        reason='',
        result=result,
        pose=estimate.T_odom_current,
        frame_covariance=sparse_inlier_covariance(result, cfg.estimator.inlier_threshold),
    )

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
A narrow view refused on a sparse stream: searched against the map's scans, not one keyframe.

A 70 deg solid-state view that turns far in one step of a sparse stream leaves the
keyframe behind: on the simulated solid state (seed 1, stride 10) scan 3 turned 32.5 deg
from the keyframe (scan 2) and shares 0.29 of its structure with it, but 0.57 with the
local map (scans 0-2), which saw the road ahead before the car turned (docs/sensors.md,
session 21's ceiling). Its prediction was 2.6 m / 31.7 deg off (the car braked into the
turn), the global registration onto the keyframe found nothing, and the seeded search
around the prediction (``seeded_search.py``) searched the keyframe within 16 deg.

So such a scan, still refused after every other review step, is searched again against a
cloud of the scans the local map was built from (:func:`map_cloud`: the keyframe and the
past keyframes it keeps, ``keyframe.relocalization_keyframes``, each placed by its
accepted pose in the keyframe's frame and prepared as one scan) from seeds around the
prediction turned up to :data:`MAP_YAWS_DEG` (the turned starts' 30 deg bound and beyond)
and moved by ``seeded_search.SEED_ALONG_M``. Each seed is matched, estimated and refined as
the seeded search does (guided re-matching, SC2-PCR, the map alignment) and the places
are judged by that search's evidence (``seeded_search.search_seeds``, the best place only):
the best covisible overlap above every distinct place and every slide by
``covisibility.accept_gap``, the best dense score, ``estimator.min_inliers`` sparse
inliers, the map inlier floor and no second basin (``near_miss.*``). Its bar is
:data:`MAP_OVERLAP` on :data:`MAP_CHECKED` of the surface: the cloud holds several views,
and the covisible test sees it from the keyframe's origin only, so the right place of scan
3 kept 0.846 on 0.10 checked (the distinct places at most 0.678; refused scans 4-5's best
places, 10.5 and 21.7 m off, 0.54 and 0.49). The near-miss check matters here: on the
120-scan seed-5 drive at stride 10 a place 1.04 m along the road from the truth reached
0.823 on 0.10 checked with the best dense score, and only its two basins refused it; on
the seed-7 drive a place 6.1 m / 87 deg off reached 0.857 on 0.042 checked, under
:data:`MAP_CHECKED` (docs/sensors.md, session 22).

It runs only on a partial view (``View.partial``) whose scan before is more than
``sparse_turn.SPARSE_GAP_S`` away, refused with a motion model's prediction (not a still
start), with at least two scans in the map's cloud. A full ring and a dense stream are
not touched (the function returns at once).
"""

from __future__ import annotations

from dataclasses import dataclass
import time
from typing import TYPE_CHECKING

from mlsemreg_ros.core.odometry.local_map import Keyframe
from mlsemreg_ros.core.odometry.seeded_search import (
    search_seeds,
    searched,
    SEED_ALONG_M,
    seed_grid,
)
from mlsemreg_ros.core.odometry.sparse_turn import refused_moving
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.odometry.motion_model import Prediction
    from mlsemreg_ros.core.odometry.odometry import Odometry
    from mlsemreg_ros.core.odometry.preprocess import PreprocessedScan
    from mlsemreg_ros.core.odometry.steps import Decision
    from mlsemreg_ros.core.odometry.tracking import Tracker

#: Yaw offsets of the seeds from the prediction (deg): scan 3 of the seed-1 drive at stride
#: 10 was 31.7 deg from its prediction.
MAP_YAWS_DEG = (-40.0, -32.0, -24.0, -16.0, -8.0, 0.0, 8.0, 16.0, 24.0, 32.0, 40.0)
#: The covisible overlap the best place must reach against the map's cloud.
MAP_OVERLAP = 0.8
#: ... on at least this share of its surface checked.
MAP_CHECKED = 0.05
#: The map's cloud needs at least this many scans (one is the keyframe the search had).
MIN_MAP_SCANS = 2


@dataclass(frozen=True)
class _MapView:
    """What ``seeded_search.search_seeds`` reads of the odometry, with the map's cloud."""

    config: RegistrationConfig
    keyframe: Keyframe
    tracker: Tracker


def map_seeds(T_predicted: np.ndarray) -> list[np.ndarray]:
    """Return the prediction turned by :data:`MAP_YAWS_DEG` and moved by ``SEED_ALONG_M``."""
    return seed_grid(T_predicted, MAP_YAWS_DEG, [(along, 0.0) for along in SEED_ALONG_M])


def map_cloud(odometry: Odometry) -> Keyframe | None:
    """
    Return the map's scans as one prepared scan in the keyframe's frame (None: too few).

    The keyframe and the past keyframes the odometry keeps (``recovery.PastKeyframes``),
    each moved by its pose relative to the keyframe; the result carries the keyframe's
    index, stamp and pose.
    """
    keyframe = odometry.keyframe
    scans = [*odometry.past_keyframes.newest_first(), keyframe]
    if keyframe is None or len(scans) < MIN_MAP_SCANS:
        return None
    points, labels = [], []
    for scan in scans:
        T = np.linalg.solve(keyframe.pose, scan.pose)
        points.append(np.asarray(scan.points, dtype=np.float64) @ T[:3, :3].T + T[:3, 3])
        labels.append(np.asarray(scan.labels).reshape(-1))
    merged_points, merged_labels = np.concatenate(points), np.concatenate(labels)
    prepared = odometry.registration.prepare(merged_points, merged_labels)
    odometry.preprocessor.exclude_moving(prepared, merged_points, merged_labels)
    return Keyframe(
        keyframe.index,
        keyframe.stamp_ns,
        merged_points,
        merged_labels,
        prepared,
        keyframe.pose.copy(),
    )


def search_local_map(
    odometry: Odometry,
    prediction: Prediction | None,
    raw: PreprocessedScan,
    chosen: Decision,
    timings: dict[str, float],
) -> Decision:
    """Return ``chosen``, or the place the search against the map's scans accepts."""
    cfg, view = odometry.config, odometry.tracker.trust.view
    registration = getattr(odometry.global_registration, 'registration', None)
    if (
        not refused_moving(chosen, prediction, view)
        or not cfg.odometry.seeded_search
        or cfg.fine.method == 'off'
        or registration is None
        or odometry.keyframe is None
        or len(odometry.past_keyframes) + 1 < MIN_MAP_SCANS
    ):
        return chosen
    tic = time.perf_counter()
    try:
        target = map_cloud(odometry)
        if target is None:
            return chosen
        place, refusal = search_seeds(
            _MapView(cfg, target, odometry.tracker),
            registration,
            map_seeds(prediction.T_odom_current),
            raw.scan,
            config=_bar(cfg),
            best_only=True,
        )
    finally:
        timings['map_search_ms'] = 1e3 * (time.perf_counter() - tic)
    name = ('map search', 'the search against the map scans')
    return searched(chosen, place, refusal, name, cfg.odometry.covariance_scale)


def _bar(cfg: RegistrationConfig) -> RegistrationConfig:
    """Return ``cfg`` with the covisible bar of the map's cloud (module docstring)."""
    return cfg.replace(
        {'covisibility.accept_overlap': MAP_OVERLAP, 'covisibility.accept_checked': MAP_CHECKED}
    )

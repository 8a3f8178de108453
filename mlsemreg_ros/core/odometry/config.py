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
The odometry's sections of the core config: ``local_map``, ``keyframe`` and ``odometry``.

Assembled by :class:`~mlsemreg_ros.core.config.RegistrationConfig` (core/config.py),
which re-exports them; fields are :func:`~mlsemreg_ros.core.settings.param` declarations.
This module imports only the settings engine, and the odometry package's ``__init__``
imports its modules lazily, so the assembly can import the sections without the odometry.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core.settings import param


@dataclass
class LocalMapConfig:
    """The odometry's local map: recent aligned scans in the odom frame, LRU-bounded."""

    horizon: int = param(
        100,
        'Voxels that no inserted scan touched during this many insertions are dropped '
        '(small_gicp LRU horizon).',
        low=1,
        high=100000,
    )
    clear_cycle: int = param(
        10, 'Insertions between two LRU clean-ups of the local map.', low=1, high=100000
    )


@dataclass
class KeyframeConfig:
    """When the current scan replaces the keyframe (after an accepted frame)."""

    policy: str = param(
        'every_frame',
        'every_frame: each registered scan becomes the keyframe (frame-to-frame '
        'odometry); distance: only once it moved keyframe.min_distance or turned '
        'keyframe.min_rotation away from the keyframe.',
        choices=('every_frame', 'distance'),
    )
    min_distance: float = param(
        1.0,
        'distance policy: translation from the keyframe that makes a new keyframe.',
        unit='m',
        low=0.0,
        high=1000.0,
    )
    min_rotation: float = param(
        10.0,
        'distance policy: rotation from the keyframe that makes a new keyframe.',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    min_points: int = param(
        1000,
        'A scan becomes a keyframe only with at least this many points after '
        'voxelization (a degenerate scan would make every later one fail).',
        low=1,
        high=10000000,
    )
    min_keypoints: int = param(
        100,
        'A scan becomes a keyframe only with at least this many keypoints (with a '
        'valid descriptor; at most keypoints.count are asked for).',
        low=3,
        high=100000,
    )
    min_structure: float = param(
        0.02,
        'A scan becomes a keyframe only if the fine alignment can pin it in every '
        'direction: the ratio of the smallest to the largest eigenvalue of the translation '
        'block of its Hessian aligned onto itself (GICP, from its normals) must reach this '
        '(measured: real scans of 12 sensors and the KITTI dev pairs 0.17 to 0.64, '
        'simulated field drives 0.34 to 0.41, a corridor 0.004, a flat ground 0.001; '
        '0: no check; not with fine.method off).',
        low=0.0,
        high=1.0,
    )
    relocalization_keyframes: int = param(
        5,
        'Past keyframes the odometry keeps: after keyframe.max_failures rejections in a '
        'row the scan is registered onto them (newest first) before a re-initialisation '
        '(0: re-initialise at once).',
        low=0,
        high=100,
    )
    max_failures: int = param(
        10,
        'After this many rejected frames in a row against one keyframe, the odometry '
        're-initialises on the current scan at the last accepted pose (the map restarts '
        'from it; 0: never).',
        low=0,
        high=100000,
    )
    restart_gap: float = param(
        1.0,
        'While no pair was accepted since the keyframe began (no motion known), a refused '
        'scan at least this long after the keyframe becomes the keyframe at once, so that the '
        'next scan is one stride from it (a VLP-16 drive at stride 20 faced the first scan '
        '37-92 m back); a refused scan closer in time waits for keyframe.max_failures as any '
        'other, so that the next scan still faces the keyframe (a solid-state drive at '
        'stride 1 went from 97 % to 0 % with every refused scan restarting; '
        'docs/evaluation.md). 0: every refused first pair restarts; unstamped scans restart.',
        unit='s',
        low=0.0,
        high=3600.0,
    )


@dataclass
class OdometryConfig:
    """
    Which estimate of a frame the odometry accepts (see core/odometry.py).

    Candidates: the global estimate (ML-SemReg + estimator onto the keyframe) composed with
    the keyframe pose, and the constant-velocity prediction; each is refined against the
    local map. A refined pose is acceptable when the fine alignment kept enough of the scan
    as inliers and moved its initial guess by no more than the correction bounds.
    """

    constant_velocity: bool = param(
        True,
        'Refine the constant-velocity prediction against the local map; when it agrees '
        'with the global estimate only one alignment is paid for, and when the global '
        'estimate fails the prediction can still be accepted.',
    )
    still_start: float = param(
        0.15,
        'Before any motion is known (the first pairs), a scan at most this long after the '
        'last accepted one is also aligned from that pose (a still start, as KISS-ICP '
        'starts): judged as a prediction, with the global registration beside it when '
        'it is not trusted alone (0: off; a car at 10 Hz moves about 1 m a scan).',
        unit='s',
        low=0.0,
        high=10.0,
    )
    turn_rate: float = param(
        45.0,
        'A scan (a full ring or a narrow view) whose decision was refused is also aligned '
        'from its prediction turned about the vertical '
        'by +-10 and +-20 deg, those within this turn rate times the time since the last '
        'accepted scan (or 1.5 times the predicted turn), and accepted on its own evidence '
        '(no rival basin, perturbed starts come back): the onset of a turn is no motion '
        "model's to predict (core/odometry/narrow_view.py; 0: off).",
        unit='deg/s',
        low=0.0,
        high=1000.0,
    )
    global_registration: str = param(
        'on_demand',
        'always: ML-SemReg + SC2-PCR onto the keyframe for every scan (the '
        'previous default; about twice the time per scan); on_demand: only when the refined '
        'prediction is not trusted (no prediction, refused, corrected by more than '
        'odometry.tracking_translation/rotation, fewer inliers than usual, a gap in the '
        'stamps) and at least every odometry.global_interval scans as a check of the motion '
        'model.',
        choices=('always', 'on_demand'),
    )
    global_interval: int = param(
        30,
        'on_demand: the longest run of scans tracked by the refined prediction alone; '
        'the next one is registered globally (1: every scan).',
        low=1,
        high=100000,
    )
    tracking_translation: float = param(
        0.5,
        'on_demand: a refined prediction that the fine alignment moved further than this '
        'is not trusted alone (the motion model did not hold).',
        unit='m',
        low=0.0,
        high=100.0,
    )
    tracking_rotation: float = param(
        4.0,
        'on_demand: a refined prediction that the fine alignment turned further than this '
        'is not trusted alone (simulated drives: up to 4 deg at the start and end of turns, '
        'with 0.97 of the scan as inliers).',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    tracking_inlier_share: float = param(
        0.9,
        'on_demand: a refined prediction is trusted alone only with at least this share '
        'of the median inlier fraction of the last accepted scans (as good as usual).',
        low=0.0,
        high=1.0,
    )
    tracking_min_inlier_fraction: float = param(
        0.7,
        'on_demand: ... and with at least this share of the scan as map inliers: '
        'tracking is for scans that overlap the map well (simulated drives: 0.97 at 1 m '
        'per scan, 0.80 at 8 m, 0.63 at 16 m; scans 20 m apart stay registered globally).',
        low=0.0,
        high=1.0,
    )
    agreement_translation: float = param(
        0.3,
        'The refined prediction agrees with the global estimate within this '
        'translation (and odometry.agreement_rotation).',
        unit='m',
        low=0.0,
        high=100.0,
    )
    agreement_rotation: float = param(
        1.0,
        'The refined prediction agrees with the global estimate within this rotation.',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    max_correction_translation: float = param(
        1.5,
        'A fine alignment that moves its initial guess further than this is not '
        'accepted (it ran away or started outside its basin).',
        unit='m',
        low=0.0,
        high=100.0,
    )
    max_correction_rotation: float = param(
        5.0,
        'A fine alignment that turns its initial guess further than this is not accepted.',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    min_inlier_fraction: float = param(
        0.25,
        "Share of the scan's alignment points that must have a correspondence "
        '(map or target scan) within fine.max_correspondence_distance after the fine '
        'alignment.',
        low=0.0,
        high=1.0,
    )
    min_relative_inlier_fraction: float = param(
        0.6,
        'The inlier fraction must also reach this share of the median inlier fraction '
        'of the last accepted frames: a pose that overlaps the map only by chance (the '
        'mirror pose of a street, a different street) keeps far fewer inliers than the '
        'frames before it (0: no such check).',
        low=0.0,
        high=1.0,
    )
    seeded_search: bool = param(
        True,
        'A scan still refused after a gap in the stamps (a lost scan before it) is matched '
        'onto the keyframe again around its prediction (turned and moved seeds, guided '
        're-matching, SC2-PCR, the map alignment), and the best place is accepted only on '
        'the evidence of stage 9: its covisible overlap with the keyframe above every '
        'distinct place and slide by covisibility.accept_gap, the best dense score, and no '
        'second basin (core/odometry/seeded_search.py).',
    )
    view_search_overlap: float = param(
        0.85,
        'A narrow view (under 0.9 of the azimuth circle) refused before any pair was '
        'accepted, further in time than odometry.still_start from the keyframe (at 10 Hz: '
        'the third scan after a refused second one, or any scan at stride 2 and up), is '
        'matched onto the keyframe '
        'again from seeds along its view axis (every 4 m up to 15 m/s times the time since '
        'the keyframe, turned by up to 16 deg), judged as odometry.seeded_search judges a '
        'place, on the two scans deskewed by the motion the best place implies; that place '
        'is accepted with this covisible overlap (covisibility.accept_overlap on a far pair: '
        'the right first pairs of the simulated solid state at 5-20 m kept 0.85-0.95; '
        'core/odometry/start_search.py; 0: off).',
        low=0.0,
        high=1.0,
    )
    view_search_checked: float = param(
        0.2,
        'The share of its surface the two scans must check for odometry.view_search_overlap '
        '(covisibility.accept_checked on a far pair): a first pair in a turn checks 0.03-0.19 '
        'and its best places were up to 0.9 m off.',
        low=0.0,
        high=1.0,
    )
    ring_search_overlap: float = param(
        0.97,
        'A full ring refused before any pair was accepted, further in time than '
        'odometry.still_start from the keyframe and from the scan before it, is matched onto '
        'the keyframe again from seeds along its forward axis (+x), as odometry.'
        'view_search_overlap does for a narrow view; that place is accepted with this '
        'covisible overlap (core/odometry/ring_start_search.py; 0: off).',
        low=0.0,
        high=1.0,
    )
    ring_search_checked: float = param(
        0.03,
        'The share of its surface the two scans must check for odometry.ring_search_overlap.',
        low=0.0,
        high=1.0,
    )
    ring_search_max_gap: float = param(
        1.0,
        'odometry.ring_search_overlap searches a first pair at most this long after the '
        'keyframe (s): strides up to 10 at 10 Hz. At 3 s (25-30 m) the covisible overlap no '
        'longer told a place 0.8 m off along a straight road from the right one (0.982 '
        'against 0.977-0.994; docs/sensors.md, session 20).',
        low=0.0,
        high=1e3,
    )
    refine_first_keyframe: bool = param(
        True,
        'The global registration onto the first keyframe after a start or reset refines the '
        "pair itself, as eval-pairs does, so the refused path's last stages (the covisible "
        'acceptance, stage 9) can judge it: the simulated field drive seed 1 at stride 20 with '
        'geometric labels went from 0 to 100 %, 0 wrong (core/odometry/global_registration.py, '
        'docs/labels.md); false: every global registration leaves the refinement to the map.',
    )
    covariance_scale: float = param(
        13.1,
        'Factor on the pose covariance inv(H) * 2E / (n - 6) of the fine alignment '
        '(H Hessian, E final error, n inliers), before the covariance section adds its '
        'floors (docs/covariance.md). Fitted with them by mlsemreg covariance-nees on real '
        'KITTI pairs and field-mode drives (2026-12-04).',
        low=1e-6,
        high=1e6,
    )

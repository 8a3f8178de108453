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
The ``fine`` and ``sweep_alignment`` sections of the core config (fine alignment).

Assembled by :class:`~mlsemreg_ros.core.config.RegistrationConfig` (core/config.py),
which re-exports them; fields are :func:`~mlsemreg_ros.core.settings.param` declarations.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core.settings import param


@dataclass
class FineAlignmentConfig:
    """
    Fine alignment of the dense scans with small_gicp, after the global estimate.

    GICP (Segal et al., RSS 2009) and VGICP (Koide et al., ICRA 2021) as implemented by
    koide3/small_gicp. Pairs: the source scan onto the target scan; odometry: the scan
    onto the local map (an LRU voxel map of the last aligned scans in the odom frame).
    """

    method: str = param(
        'vgicp',
        'Odometry: alignment of each scan to the local map. vgicp (voxelized GICP; '
        'the map is a Gaussian voxel map), gicp, plane_icp (point-to-plane), icp '
        '(point-to-point; with gicp/plane_icp/icp the map points are indexed again every '
        'frame, slower) or off (the estimate as it is, chained scan to keyframe).',
        choices=('vgicp', 'gicp', 'plane_icp', 'icp', 'off'),
    )
    pair_method: str = param(
        'gicp',
        'Pairs (Registration.register, mlsemreg eval-pairs): alignment of the source '
        'scan onto the target scan, both as voxelized at features.voxel_size. gicp, vgicp, '
        'plane_icp, icp or off (the estimate as it is).',
        choices=('gicp', 'vgicp', 'plane_icp', 'icp', 'off'),
    )
    downsampling_resolution: float = param(
        0.5,
        'Odometry: voxel edge to which the scan (already voxelized at '
        'features.voxel_size) is downsampled for the map alignment (0: as it is). '
        'Scaled with a sparse sensor (fine.scale_with_sensor) unless set.',
        unit='m',
        low=0.0,
        high=5.0,
    )
    scale_with_sensor: bool = param(
        True,
        "Odometry: measure the first scan's angular point spacing and, on a sensor sparser "
        'than a 64-beam one, scale fine.downsampling_resolution by it (up to x2) and '
        'keyframe.min_points by its inverse square; on a small scene (its 90th-percentile '
        'range under 12 m: a room) widen the angles that judge a coarse pose '
        '(odometry.max_correction_rotation, levelling.tolerance, '
        'geometric_labels.tilt_tolerance, near_miss.agreement_rotation) by 12 m over that '
        'range (up to x1.6), shrink the near-miss starts (near_miss.offset) by as much, and '
        'label a cloud without a label field with label_source '
        'auto as none (the geometric labeler is a street one); and shrink the map alignment '
        'grids by as much: fine.voxel_size, and fine.downsampling_resolution from its '
        'default instead of the spacing scale (half the voxel). A value the user set (other '
        'than the default) is kept (core/odometry/sensor_scale.py, docs/sensors.md).',
    )
    voxel_size: float = param(
        1.0,
        'VGICP voxel edge: of the local map and of the target scan of a pair; with '
        "gicp/plane_icp/icp, the edge of the local map's point cells.",
        unit='m',
        low=0.05,
        high=10.0,
    )
    num_neighbors: int = param(
        10,
        'Odometry: neighbours of each alignment point for its covariance and normal '
        '(simulated drives: 10 drifted less than 20 at strides 10 and 20, and costs less).',
        low=5,
        high=200,
    )
    pair_num_neighbors: int = param(
        20,
        'Pairs: neighbours of each point for its covariance and normal (KITTI dev pairs: '
        'rotation error 0.24 deg with 20, 0.28 deg with 10).',
        low=5,
        high=200,
    )
    max_correspondence_distance: float = param(
        1.0,
        'Maximum distance of a point to its correspondence (its inlier bound).',
        unit='m',
        low=0.05,
        high=20.0,
    )
    max_iterations: int = param(20, 'Maximum Gauss-Newton iterations.', low=1, high=1000)
    refused_downsampled: bool = param(
        True,
        'Pairs: a pose the confidence rule still refuses is refined with the source scan '
        'downsampled to fine.downsampling_resolution, as the polishing of refused candidates '
        'does (a third of its GICP time; the pose stays refused). The covisible refinement '
        '(covisibility.refine_distance) uses the same source cloud: 60 m dev pairs 8 of 16 '
        'within bounds with either descriptor on, GEDI 8 and FPFH 7 off (docs/long_range.md).',
    )
    rotation_epsilon: float = param(
        0.01,
        'Convergence: the iterations stop once an update turns less than this (and '
        'moves less than fine.translation_epsilon); the small_gicp default of 0.1 deg leaves '
        'up to ~0.1 deg of error, which drifts at large strides.',
        unit='deg',
        low=1e-6,
        high=10.0,
    )
    translation_epsilon: float = param(
        1e-4,
        'Convergence: the iterations stop once an update moves less than this.',
        unit='m',
        low=1e-8,
        high=1.0,
    )


@dataclass
class SweepAlignmentConfig:
    """Continuous-time alignment of a sweep deskewed without a gyro (docs/field.md)."""

    mode: str = param(
        'auto',
        'auto: a scan deskewed by a constant twist from the poses (no gyro over the sweep) '
        'is aligned once more to the local map with the motion within its sweep free (the '
        'pose at the stamp and the sweep twist, as CT-ICP); when that twist bends the scan '
        'by more than sweep_alignment.min_change, the scan is deskewed with it and aligned '
        'again. off: the deskew twist is kept.',
        choices=('auto', 'off'),
    )
    points: int = param(
        1000,
        'Raw points in the sweep alignment (every k-th point of the sweep, movable classes '
        'left out; 2000 before issue 35: the same poses at a higher cost, docs/sensors.md).',
        low=100,
        high=1000000,
    )
    iterations: int = param(
        5,
        'Gauss-Newton steps of the sweep alignment (the robust kernel narrows from a '
        'scale of 64 to 1 by the second-to-last step).',
        low=1,
        high=100,
    )
    max_distance: float = param(
        1.0,
        'A point pairs with its nearest map voxel mean only within this distance.',
        unit='m',
        low=0.05,
        high=20.0,
    )
    rate_sigma: float = param(
        1.0,
        'Prior standard deviation of the sweep angular rate about the deskew twist.',
        unit='rad/s',
        low=1e-4,
        high=100.0,
    )
    velocity_sigma: float = param(
        1.0,
        'Prior standard deviation of the sweep velocity about the deskew twist.',
        unit='m/s',
        low=1e-4,
        high=100.0,
    )
    steady_correction: float = param(
        0.05,
        'A scan tracked by its prediction that the fine alignment moved by less than this '
        '(and sweep_alignment.steady_rotation) is not aligned again: the motion model held, '
        'so the sweep is deskewed by the motion it already had (0: every scan is; VLP-16 at '
        '10 Hz: 65 % of the scans, a median correction of 2 cm; docs/sensors.md).',
        unit='m',
        low=0.0,
        high=10.0,
    )
    steady_rotation: float = param(
        0.2,
        '... and turned by less than this.',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    min_change: float = param(
        0.5,
        'The scan is deskewed with the estimated twist and aligned again only when that '
        'twist moves some point of the subset by more than this (0.25 m redid 37 % of the '
        'VLP-16 and 44 % of the solid-state scans on noise of the 1000-point estimate, for '
        'the same errors; docs/sensors.md).',
        unit='m',
        low=0.0,
        high=10.0,
    )
    gap_after: float = param(
        1.0,
        'A full-ring scan accepted more than this after the last accepted one, deskewed by '
        'the twist of the poses (no gyro), is deskewed again with the velocity from the last '
        'accepted pose to its own and no rotation rate, aligned again, and its sweep '
        'alignment then holds that velocity (sweep_alignment.gap_velocity_sigma): over a gap '
        'of seconds the poses twist spans a turn the car has left (the HDL-64 field drives '
        'at stride 30: 2 near misses fewer, none added; docs/confidence.md, session 22). '
        '0: off.',
        unit='s',
        low=0.0,
        high=60.0,
    )
    gap_velocity_sigma: float = param(
        0.1,
        'Prior standard deviation of the sweep velocity about the gap velocity, in the sweep '
        'alignment of a scan deskewed again over a gap (sweep_alignment.gap_after): along a '
        'street the velocity is weakly held, and a local map bent by an earlier sweep pulled '
        'it 3 m/s sideways with velocity_sigma.',
        unit='m/s',
        low=1e-4,
        high=100.0,
    )


@dataclass
class NearMissConfig:
    """
    The near-miss check of an accepted pair pose (docs/confidence.md#near-misses).

    After the fine alignment, the pair is aligned again from ``near_miss.starts``
    perturbed poses; a start that converges elsewhere to a place about as good as the
    refined pose (a second basin) disputes it.
    """

    enabled: bool = param(
        True,
        'Check an accepted pose for a second basin: the fine alignment again from '
        'perturbed starts must come back to the same place, or land somewhere clearly '
        'worse (pairs: core/stages/near_miss.py; odometry: a pose decided on the global '
        'registration or the prediction alone, and a refused candidate judged on its own '
        'evidence, core/odometry/second_look.py). false: neither.',
    )
    action: str = param(
        'refuse',
        'A disputed pose: refuse it, or inflate its covariance along the disputed '
        'direction until its standard deviation there covers the gap between the basins.',
        choices=('refuse', 'inflate'),
    )
    recheck_swept: bool = param(
        True,
        'The odometry, with near_miss.action refuse: a scan refused for a disputed pose '
        "that no later path accepts goes on with that pose to the start's deskew and the "
        'sweep alignment, and is accepted if the basins no longer dispute the pose they '
        'give on the scan deskewed again (core/odometry/swept_dispute.py). A sweep bent by a '
        'wrong twist shows two basins that are both artefacts: on the HDL-64 and HDL-32 '
        'field drives (seed 7, stride 5) both lay 0.55-0.65 m off, the swept pose 0.02 and '
        '0.08 m (docs/confidence.md, session 19).',
    )
    move_to_better_place: bool = param(
        False,
        'The odometry: a disputed pose whose rival basin fits the map better (more inliers, '
        'lower residual) moves there when that basin passes the check itself (true), or is '
        'judged by near_miss.action (false). Moving published a pose 0.649 m off on a '
        'field drive at stride 30 (a scan deskewed 20 deg/s wrong; the rival basin was the '
        'wrong one), and on the field drives at strides 1, 10, 20 and 30 false loses no '
        'scan (docs/confidence.md).',
    )
    starts: int = param(
        4,
        'Perturbed starts: 2 = along the weakest horizontal direction of the Hessian, both '
        'ways; 4 adds the perpendicular direction, both ways (the weakest direction of a '
        'nearly isotropic Hessian says little: a fence of posts 0.8 m apart was caught '
        'from both sides only with 4).',
        low=2,
        high=4,
    )
    max_inliers: int = param(
        200,
        'Pairs: a pose whose sparse consensus holds more inliers than this is not checked '
        '(0: every accepted pose is). The check doubles the time of a 20 m dev pair (about '
        '400 ms of 1040), whose accepted poses hold 367-947 inliers; the accepted 40 m poses '
        'hold 41-133, where near misses were seen.',
        low=0,
        high=1000000,
    )
    pair_downsampled: bool = param(
        False,
        'Pairs: the perturbed starts are aligned with the source scan downsampled to '
        'fine.downsampling_resolution (the refined pose and every basin are still judged '
        'on the full scan): about a third of their GICP time. Off: with the covisible '
        'acceptance it changed three 60 m verdicts, two right poses accepted and one lost '
        '(docs/hard_pairs.md).',
    )
    offset: float = param(
        0.6,
        'Translation of each perturbed start from the refined pose.',
        unit='m',
        low=0.05,
        high=5.0,
    )
    yaw_offset: float = param(
        1.0,
        'Yaw of each perturbed start from the refined pose (the sign follows the shift).',
        unit='deg',
        low=0.0,
        high=20.0,
    )
    home_iterations: int = param(
        4,
        'Pairs: each perturbed start is first aligned for this many iterations; a start '
        'then within near_miss.home_share of the agreement bounds of the refined pose (when '
        'that converged) is back home (it agrees) and stops there; any other start is '
        'aligned again from its start with the full fine.max_iterations, as without this '
        '(0: every start runs to convergence). On the 40 m dev chains a start 0.6 m off '
        'needs 7-19 iterations to converge; 21 of 28 were home after 4 '
        '(docs/hard_pairs.md, sixth round).',
        low=0,
        high=1000,
    )
    home_share: float = param(
        0.25,
        'Share of near_miss.agreement_translation and near_miss.agreement_rotation '
        'within which a start after near_miss.home_iterations is back home.',
        low=0.0,
        high=1.0,
    )
    agreement_translation: float = param(
        0.4,
        'A perturbed start that converges within this translation (and '
        'near_miss.agreement_rotation) of the refined pose came back to the same place '
        '(0.2 refused a right pose of a field drive at stride 20 for a place 0.37 m away: '
        'two places that close are both within the 0.6 m bound).',
        unit='m',
        low=0.001,
        high=5.0,
    )
    agreement_rotation: float = param(
        1.0,
        'Rotation of near_miss.agreement_translation.',
        unit='deg',
        low=0.001,
        high=20.0,
    )
    rival_share: float = param(
        0.95,
        'Another basin disputes the refined pose when its inlier share is at least this '
        "times the refined pose's (and its point-to-distribution residual at most "
        "1/rival_share times the refined pose's); a clearly worse basin does not.",
        low=0.0,
        high=1.0,
    )
    min_weak_support: float = param(
        10.0,
        'The odometry: a candidate accepted on its own evidence (core/odometry/second_look.py) '
        "needs at least this many inliers' worth of information along its alignment's "
        'weakest direction (the Hessian with 5 deg weighing as 0.6 m, '
        'core/alignment/weak_direction.py; 0: not checked). Solid-state scans of a road '
        'accepted 0.78 and 0.96 m off had the support of 5.2 and 2.8; the KITTI dev '
        "chain's scan 7, right, 34.7 (docs/confidence.md).",
        low=0.0,
        high=10000.0,
    )
    weak_confirmation: float = param(
        0.3,
        'The odometry: a candidate accepted on its own evidence whose weakest direction '
        'holds less than near_miss.min_weak_support is accepted only if the sweep alignment '
        '(the scan and, on a start, the first scan deskewed by the motion the candidate '
        'implies, then the sweep twist free) keeps a pose within this distance of it; else '
        'it is refused (0: refused outright). Right solid-state first registrations moved '
        '0.10-0.21 m; a wrong one 0.82 m, another was not kept (docs/sensors.md).',
        unit='m',
        low=0.0,
        high=5.0,
    )
    start_twist_spread: float = param(
        0.4,
        'The odometry, without a gyro: the first pair is aligned once more onto its first '
        'scan deskewed with no rotation rate (its twist is unknown); a pose that moves more '
        'than this is judged by near_miss.start_twist_action '
        '(core/odometry/start_twist.py; 0: not checked). The HDL-64 field drive (seed 0) '
        'accepted its first pair 0.57 and 0.54 m off at strides 20 and 30, moving 0.56 m; '
        'right first pairs of the field drives moved 0.01-0.33 m (docs/confidence.md).',
        unit='m',
        low=0.0,
        high=5.0,
    )
    start_twist_action: str = param(
        'inflate',
        'A first pair beyond near_miss.start_twist_spread: its frame covariance grows along '
        'the gap between the two poses until its standard deviation there covers it '
        '(inflate), or it is refused and the odometry restarts on the newer scan (refuse: '
        'on the HDL-64 field drive the restarted pair then lost a right pose at stride 20 '
        'and published one 0.72 m off at stride 30, docs/confidence.md).',
        choices=('inflate', 'refuse'),
    )
    max_residual: float = param(
        0.0,
        'Refuse a refined pose whose mean point-to-distribution residual (squared '
        'Mahalanobis distance of the source points to their nearest target Gaussians, '
        'inliers only) exceeds this (0: not checked).',
        low=0.0,
        high=1000.0,
    )

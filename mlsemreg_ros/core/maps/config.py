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
The ``map`` section of the core config (mapping, relocalization).

Assembled by :class:`~mlsemreg_ros.core.config.RegistrationConfig` (core/config.py),
which re-exports them; fields are :func:`~mlsemreg_ros.core.settings.param` declarations.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core.settings import param


@dataclass
class MapConfig:
    """
    The keyframe map: store, place recognition, relocalization, loop closure (docs/maps.md).

    Keyframes are kept in the map frame with their labeled, voxelized scans; a query is
    relocalized without an initial guess by registering it onto the keyframes whose
    semantic scan context is most similar.
    """

    load_path: str = param(
        '',
        'Map folder loaded at startup (docs/maps.md); the node starts unlocalized and '
        "relocalizes against it ('': no map).",
    )
    save_path: str = param(
        '', "Map folder written by the mlsemreg/save_map service ('': the service refuses)."
    )
    frame_id: str = param('map', 'Frame of the map (parent of odom_frame in TF).')
    max_keyframes: int = param(
        5000,
        'Most keyframes kept; beyond it the most redundant one (closest to another) is dropped.',
        low=1,
        high=10000000,
    )
    max_memory_mb: float = param(
        1024.0,
        "Most memory of the keyframes' points, labels and descriptors; beyond it the most "
        'redundant keyframe is dropped (prepared scans are cached apart, map.prepared_cache).',
        unit='MB',
        low=1.0,
        high=1e6,
    )
    keyframe_distance: float = param(
        2.0,
        'An accepted scan becomes a map keyframe once it is this far from the last one.',
        unit='m',
        low=0.0,
        high=1000.0,
    )
    keyframe_rotation: float = param(
        30.0,
        '... or turned this much from it.',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    prepared_cache: int = param(
        16,
        'Prepared keyframe scans (keypoints, descriptors, KD-trees) kept for registration; '
        'the least recently used are dropped and prepared again when needed.',
        low=1,
        high=100000,
    )
    prepare_on_load: bool = param(
        True,
        'Prepare the place index and up to map.prepared_cache keyframes (features and '
        'alignment clouds) when a map is loaded, so that a relocalization does not pay for '
        'them (the node does it in the background).',
    )
    rings: int = param(20, 'Rings of the semantic scan context.', low=2, high=200)
    sectors: int = param(60, 'Sectors of the semantic scan context.', low=4, high=720)
    max_radius: float = param(
        60.0,
        'Radius of the semantic scan context (points farther away are left out).',
        unit='m',
        low=1.0,
        high=500.0,
    )
    descriptor_candidates: int = param(
        30,
        'Nearest keyframes by ring key (KD-tree) that are re-ranked by the scan context '
        'over every yaw.',
        low=1,
        high=100000,
    )
    candidates: int = param(
        5,
        'Keyframes a relocalization registers onto, best scan context first (the cost of '
        'a relocalization is at most this many registrations, whatever the map size).',
        low=1,
        high=1000,
    )
    candidate_separation: float = param(
        3.0,
        'A candidate keyframe closer than this to a better one is skipped (its scan '
        'would give the same answer).',
        unit='m',
        low=0.0,
        high=1000.0,
    )
    stop_at_first_accepted: bool = param(
        True,
        'Stop at the first candidate whose registration is accepted (else register onto '
        'every candidate and keep the accepted one with the most inliers).',
    )
    quick_first: bool = param(
        True,
        'With map.stop_at_first_accepted: register every candidate first without the BEV '
        'search and the refused path, and keep the first whose pose is accepted on strong '
        'evidence (the full registration would return the same); only then register the '
        'candidates again with the full path (core/maps/relocalization.py).',
    )
    quick_defers_retry: bool = param(
        True,
        'In the quick pass (map.quick_first), a candidate on which SC2-PCR would run again '
        'on the full graph (estimator.graph_retry_inliers) is set aside after its sampled '
        'estimate until every other candidate had its quick try; then the set-aside ones '
        'get theirs, most sampled inliers first. The accepted poses are the same; a wrong '
        'place ranked first costs less.',
    )
    relocalize_after_failures: int = param(
        2,
        'A lost odometry (this many rejected scans in a row) relocalizes against its own '
        'keyframes instead of waiting for keyframe.max_failures (0: never).',
        low=0,
        high=100000,
    )
    track_distance: float = param(
        10.0,
        'Localized on a loaded map: every this many metres travelled the scan is '
        'registered onto the nearby map keyframes to correct map -> odom (0: never).',
        unit='m',
        low=0.0,
        high=1e6,
    )
    loop_closure: bool = param(
        True, 'Close loops while mapping: revisits found by place recognition, verified.'
    )
    loop_min_travel: float = param(
        30.0,
        'A keyframe is a loop candidate only if the trajectory travelled at least this '
        'far since it.',
        unit='m',
        low=0.0,
        high=1e6,
    )
    loop_search_radius: float = param(
        50.0,
        'Loop candidates farther than this from the current pose (by the drifting '
        'odometry) are not tried (0: any distance).',
        unit='m',
        low=0.0,
        high=1e6,
    )
    loop_candidates: int = param(
        2,
        'Loop candidates registered per new keyframe (best scan context first).',
        low=1,
        high=100,
    )
    loop_min_similarity: float = param(
        0.4,
        'A loop candidate is registered only if its scan context similarity reaches this.',
        low=0.0,
        high=1.0,
    )
    loop_refine: bool = param(
        True,
        'Refine each loop registration against a submap of the matched keyframe and its '
        'neighbours (GICP, the fine section) and keep the loop only if the refinement '
        'agrees (map.submap_*, core/maps/submap_check.py).',
    )
    relocalize_refine: bool = param(
        True,
        'The same check for a relocalization: the accepted registration is refined against '
        'the submap of its keyframe and refused unless the refinement agrees (map.submap_*).',
    )
    submap_keyframes: int = param(
        3,
        'Keyframes on each side of the matched one in the submap a loop or a relocalization '
        'is refined against.',
        low=0,
        high=1000,
    )
    submap_min_inlier_fraction: float = param(
        0.5,
        'A loop or relocalization whose submap refinement keeps less of the scan as '
        'inliers is refused.',
        low=0.0,
        high=1.0,
    )
    submap_max_correction_translation: float = param(
        0.3,
        'A loop or relocalization whose submap refinement moves the registration further '
        'is refused.',
        unit='m',
        low=0.0,
        high=1000.0,
    )
    submap_max_correction_rotation: float = param(
        1.5,
        '... or turns it more.',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    odometry_sigma_translation: float = param(
        0.05,
        'Pose graph: standard deviation of an odometry edge per metre travelled.',
        unit='m/m',
        low=1e-6,
        high=10.0,
    )
    odometry_sigma_rotation: float = param(
        0.2,
        'Pose graph: standard deviation of an odometry edge rotation per metre travelled.',
        unit='deg/m',
        low=1e-6,
        high=100.0,
    )
    loop_sigma_translation: float = param(
        0.1, 'Pose graph: standard deviation of a loop edge.', unit='m', low=1e-6, high=10.0
    )
    loop_sigma_rotation: float = param(
        0.5,
        'Pose graph: standard deviation of a loop edge rotation.',
        unit='deg',
        low=1e-6,
        high=100.0,
    )
    export_voxel: float = param(
        0.2,
        '`mlsemreg map export`: voxel edge of the exported point map (0: every keyframe point).',
        unit='m',
        low=0.0,
        high=10.0,
    )
    import_radius: float = param(
        40.0,
        '`mlsemreg map import`: each keyframe is the point map within this horizontal '
        'distance of its pose.',
        unit='m',
        low=1.0,
        high=500.0,
    )
    import_visible_only: bool = param(
        False,
        '`mlsemreg map import`: keep only the map points visible from the keyframe pose '
        '(Open3D hidden point removal), so a keyframe looks like a scan from there.',
    )
    import_grid: float = param(
        10.0,
        '`mlsemreg map import` without a trajectory: keyframe poses on a horizontal grid of '
        'this spacing (cells with map points around them).',
        unit='m',
        low=0.5,
        high=500.0,
    )
    import_sensor_height: float = param(
        1.73,
        '`mlsemreg map import` without a trajectory: height of a grid keyframe above the '
        'lowest map points around it (the sensor height of the drive).',
        unit='m',
        low=0.0,
        high=100.0,
    )

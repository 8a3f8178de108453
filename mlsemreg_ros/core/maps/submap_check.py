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
A registration's second opinion: the scan refined against a submap of the matched place.

Used for loop edges (``map.loop_refine``, core/maps/mapping.py) and relocalizations
(``map.relocalize_refine``, core/maps/relocalization.py). A registration onto a keyframe
(ML-SemReg, SC2-PCR, scan-to-scan GICP) can find the right place and
still be a metre off: two single scans of a street, seen from opposite directions and
lanes, overlap little, and GICP between them settles where their few shared surfaces
agree. The matched keyframe's neighbours saw the same place from nearby, so together they
cover what the current scan sees. Their poses relative to the matched keyframe come from
the odometry over a few metres, which is locally exact.

:func:`refine_on_submap` builds that submap (``map.submap_keyframes`` keyframes on each
side of the match, in the match's frame), aligns the current scan onto it with small_gicp's
GICP (the fine-alignment settings of the ``fine`` section) from the registration's pose,
and says whether the pose is kept:

- the refinement must keep ``map.submap_min_inlier_fraction`` of the scan as inliers;
- it must agree with the registration: move it by at most ``map.submap_max_correction_*``
  (a refinement that runs beyond that found another minimum, or the registration was
  wrong by more than a refinement can tell; either way the pose is not trusted);
- the refined pose replaces the registration's (the submap's is the better measurement:
  more of the place, the poses that the map already holds).

This is the scan-to-submap check of loop closure in LiDAR SLAM systems (e.g. the ICP of
the scan against the loop keyframe's neighbours in LIO-SAM's ``performLoopClosure``,
Shan et al. 2020).
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core.alignment.alignment import align_pair, AlignmentCloud
from mlsemreg_ros.core.config import FineAlignmentConfig, MapConfig
from mlsemreg_ros.core.maps.keyframe_store import KeyframeStore
from mlsemreg_ros.core.results import PreparedScan
from mlsemreg_ros.core.rigid import invert_transform, rotation_angle_deg
import numpy as np


@dataclass
class SubmapCheck:
    """The verdict on one registration (``T_match_current``: the pose to use if ``accepted``)."""

    accepted: bool
    T_match_current: np.ndarray  # the refined pose
    T_registration: np.ndarray  # the registration's pose it was refined from
    correction_m: float = 0.0  # how far the submap refinement moved the registration's pose
    correction_deg: float = 0.0
    inlier_fraction: float = 0.0
    submap_keyframes: int = 0
    reason: str = ''  # why it was refused ('' if accepted)


def submap_points(
    store: KeyframeStore, match: int, neighbours: int, allowed: set[int]
) -> tuple[np.ndarray, int]:
    """
    Points (M, 3) of keyframe ``match`` and its ``neighbours`` on each side, in its frame.

    The neighbours are the keyframes next to it in insertion order (the odometry's order),
    restricted to ``allowed`` (e.g. the loop candidates: left long enough ago). Returns the
    points and the number of keyframes used.
    """
    ids = store.ids
    at = ids.index(match)
    chosen = [
        k
        for k in ids[slice(max(at - neighbours, 0), at + neighbours + 1)]
        if k == match or k in allowed
    ]
    T_match_map = invert_transform(store[match].T_map_keyframe)
    clouds = []
    for k in chosen:
        T_match_k = T_match_map @ store[k].T_map_keyframe
        points = store[k].points.astype(np.float64)
        clouds.append(points @ T_match_k[:3, :3].T + T_match_k[:3, 3])
    return np.concatenate(clouds, axis=0), len(chosen)


def submap_cloud(
    store: KeyframeStore,
    match: int,
    neighbours: int,
    allowed: set[int],
    fine: FineAlignmentConfig,
) -> tuple[AlignmentCloud, int]:
    """
    Return the submap of :func:`submap_points` as small_gicp aligns onto it, and its size.

    Downsampled to ``fine.downsampling_resolution``, covariances from
    ``fine.pair_num_neighbors`` neighbours; cached in the store until it changes
    (:meth:`KeyframeStore.derived`), so that a place checked again, or prepared when the
    map was loaded (``map.prepare_on_load``), costs no second build.
    """
    ids = store.ids
    at = ids.index(match)
    chosen = tuple(
        k
        for k in ids[slice(max(at - neighbours, 0), at + neighbours + 1)]
        if k == match or k in allowed
    )
    resolution, count = fine.downsampling_resolution, fine.pair_num_neighbors

    def build() -> tuple[AlignmentCloud, int]:
        points, used = submap_points(store, match, neighbours, allowed)
        return AlignmentCloud.build(points, resolution, count), used

    return store.derived(('submap', match, chosen, resolution, count), build)


def refine_on_submap(
    store: KeyframeStore,
    match: int,
    current_points: np.ndarray,
    T_match_current: np.ndarray,
    allowed: set[int],
    cfg: MapConfig,
    fine: FineAlignmentConfig,
) -> SubmapCheck:
    """
    Refine a registration onto keyframe ``match`` against its submap and judge it (module doc).

    ``current_points`` (N, 3): the registered scan in its sensor frame;
    ``T_match_current``: the registration's pose of it in the matched keyframe's frame.
    """
    T_match_current = np.asarray(T_match_current, dtype=np.float64)
    target, used = submap_cloud(store, match, cfg.submap_keyframes, allowed, fine)
    resolution = fine.downsampling_resolution
    source = AlignmentCloud.build(current_points, resolution, fine.pair_num_neighbors)
    alignment = align_pair(source, target, T_match_current, fine, method='gicp')
    refined = alignment.T_target_source
    moved = alignment.correction
    shift, turn = float(np.linalg.norm(moved[:3, 3])), rotation_angle_deg(moved)
    check = SubmapCheck(
        False, refined, T_match_current.copy(), shift, turn, alignment.inlier_fraction, used
    )
    if not np.all(np.isfinite(refined)):
        check.reason = 'non-finite submap refinement'
    elif alignment.inlier_fraction < cfg.submap_min_inlier_fraction:
        check.reason = (
            f'submap refinement kept {alignment.inlier_fraction:.2f} of the scan as inliers '
            f'< map.submap_min_inlier_fraction={cfg.submap_min_inlier_fraction:g}'
        )
    elif (
        shift > cfg.submap_max_correction_translation or turn > cfg.submap_max_correction_rotation
    ):
        check.reason = (
            f'submap refinement moved the registration by {shift:.2f} m / {turn:.2f} deg > '
            f'map.submap_max_correction_translation/rotation='
            f'{cfg.submap_max_correction_translation:g} m / '
            f'{cfg.submap_max_correction_rotation:g} deg'
        )
    else:
        check.accepted = True
    return check


def static_points(scan: PreparedScan) -> np.ndarray:
    """Return the scan's points without those marked as moving objects (``scan.map_excluded``)."""
    if scan.map_excluded is None:
        return scan.points
    return scan.points[~scan.map_excluded]

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
The odometry's maps: the local map it tracks against, and the keyframe it registers onto.

The odometry holds one ``map`` object with this interface (a keyframe store or another
backend plugs in here, see ``docs/extending.md``)::

    map.insert_scan(scan, T_map_scan) an accepted, aligned scan joins the map
    map.align_scan(scan, T_initial)   Alignment: T_map_scan refined against the map
    map.gaussians()                   the map's means and covariances (the sweep alignment)
    map.clear()                       forget every scan (reset, re-initialisation)
    map.reconfigure(fine, local_map)  new settings; True when the map was cleared
    len(map), map.points()            occupied voxels; coordinates for display

The keyframe policy (:func:`is_new_keyframe`, :func:`keyframe_refusal`) decides which
accepted scan becomes the :class:`Keyframe`.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

from mlsemreg_ros.core import threads
from mlsemreg_ros.core.alignment.alignment import (
    _alignment,
    _failed,
    _REGISTRATION_TYPES,
    _solver_settings,
    Alignment,
    AlignmentCloud,
)
from mlsemreg_ros.core.alignment.fine_alignment import alignment_cloud
from mlsemreg_ros.core.config import (
    FineAlignmentConfig,
    KeyframeConfig,
    LocalMapConfig,
    RegistrationConfig,
)
from mlsemreg_ros.core.deferred import deferred_attribute, stored
from mlsemreg_ros.core.results import PreparedScan
from mlsemreg_ros.core.rigid import rotation_angle_deg
import numpy as np
import small_gicp

#: A map's Gaussians: means (V, 3) and covariances (V, 3, 3), odom frame.
Gaussians = tuple[np.ndarray, np.ndarray]

#: The read of the map's Gaussians for the next scan, started after an insertion.
_PREFETCH_POOL = threads.LazyPool('mlsemreg-map-prefetch')


class LocalMap:
    """
    The odometry's local map in the odom frame: recent aligned scans, LRU-bounded.

    ``vgicp`` keeps a :class:`small_gicp.GaussianVoxelMap` (one Gaussian per
    ``fine.voxel_size`` voxel) and aligns against it directly. The point-based methods
    keep a :class:`small_gicp.IncrementalVoxelMap` of points and index its points
    (KD-tree, normals, covariances) again after every insertion, which costs more.
    Voxels that no insertion touched for ``local_map.horizon`` insertions are dropped.
    """

    def __init__(self, fine: FineAlignmentConfig, local_map: LocalMapConfig) -> None:
        self.fine, self.config = fine, local_map
        self._map: small_gicp.GaussianVoxelMap | small_gicp.IncrementalVoxelMap
        self._indexed: AlignmentCloud | None = None  # point maps: the map as a target
        self.insertions = 0
        self._version = 0  # changes at every insertion and clear
        self._pending: Future[Any] | None = None  # a read started by prefetch()
        self.clear()

    def prefetch(self, then: Callable[[Gaussians | None], Any]) -> bool:
        """
        Read the map's Gaussians and pass them to ``then`` on a second thread.

        For the next scan's sweep alignment, read once the map is final for this scan: the
        copy of the Gaussians (and what ``then`` makes of them: the means sorted in cells)
        run beside what follows (the caller's own work, the next scan's arrival, its
        preprocessing) instead of in the next scan's series of steps. The same arrays as a
        read on demand (:meth:`gaussians` returns them). Every read or change of the map
        waits for it first (:meth:`settle`). Nothing with one worker (``threads: 1``): read
        on demand. Returns whether it started.
        """
        self.settle()
        self._pending = _PREFETCH_POOL.submit(lambda: then(self._read_gaussians()))
        return self._pending is not None

    def settle(self) -> None:
        """Wait for a read started by :meth:`prefetch` (a failed one is done again on demand)."""
        pending, self._pending = self._pending, None
        if pending is not None:
            try:
                pending.result()
            except Exception:  # the read on demand raises it again
                pass

    def clear(self) -> None:
        """Forget every scan (a reset); the next insertion starts a new map."""
        self.settle()
        if self.fine.method == 'vgicp':
            self._map = small_gicp.GaussianVoxelMap(self.fine.voxel_size)
        else:
            self._map = small_gicp.IncrementalVoxelMap(self.fine.voxel_size)
        self._map.set_lru(self.config.horizon, self.config.clear_cycle)
        self._indexed = None
        self._gaussians = None
        self.insertions = 0
        self._version += 1

    def reconfigure(self, fine: FineAlignmentConfig, local_map: LocalMapConfig) -> bool:
        """Take new settings; the map is cleared when its structure changed (returns True)."""
        rebuild = (fine.method, fine.voxel_size) != (self.fine.method, self.fine.voxel_size)
        lru = (local_map.horizon, local_map.clear_cycle) != (
            self.config.horizon,
            self.config.clear_cycle,
        )
        self.settle()
        self.fine, self.config = fine, local_map
        if rebuild:
            self.clear()
        elif lru:
            self._map.set_lru(local_map.horizon, local_map.clear_cycle)
        return rebuild

    def __len__(self) -> int:
        """Occupied voxels."""
        return int(self._map.size())

    @property
    def empty(self) -> bool:
        """Whether no scan was inserted since the last clear."""
        return self.insertions == 0

    def points(self) -> np.ndarray:
        """Return the map as coordinates (V, 3), odom frame: voxel means or cell points."""
        if len(self) == 0:
            return np.zeros((0, 3))
        return np.asarray(self._map.voxel_points(), dtype=np.float64)[:, :3]

    def gaussians(self) -> Gaussians | None:
        """
        Return the map's Gaussians: means (V, 3) and covariances (V, 3, 3), odom frame.

        ``vgicp``: the voxels' own; point maps: the indexed points' (None when empty). The
        same arrays until the map changes (an insertion, a clear): do not modify them. Read
        when first asked after a change, not in the insertion: a copy started on the pool
        right after each insertion held the GIL while the scan's own keyframe check went on
        (docs/sensors.md, session 17). The tracker starts one once the scan's step is made
        (:meth:`prefetch`, session 21); this waits for it.
        """
        if self._pending is not None:
            self.settle()
        return self._read_gaussians()

    def _read_gaussians(self) -> Gaussians | None:
        """:meth:`gaussians` without waiting for a prefetch (the prefetch's own read)."""
        if len(self) == 0:
            return None
        if self._gaussians is not None:  # the map did not change since they were copied
            return self._gaussians
        if isinstance(self._map, small_gicp.GaussianVoxelMap):
            self._gaussians = voxel_gaussians(self._map)
            return self._gaussians
        if self._indexed is None:
            self._indexed = AlignmentCloud.build(self.points(), 0.0, self.fine.num_neighbors)
        cloud = self._indexed.cloud
        return (
            np.asarray(cloud.points(), dtype=np.float64)[:, :3],
            np.asarray(cloud.covs(), dtype=np.float64).reshape(-1, 4, 4)[:, :3, :3],
        )

    def cloud(self, scan: PreparedScan) -> AlignmentCloud:
        """Return the map's cloud of ``scan`` (``fine.downsampling_resolution``, cached on it)."""
        return alignment_cloud(scan, self.fine)

    def insert_scan(self, scan: PreparedScan, T_map_scan: np.ndarray) -> None:
        """Add a prepared, aligned scan at ``T_map_scan`` (nothing with ``fine.method: off``)."""
        if self.fine.method != 'off':
            self.insert(self.cloud(scan), T_map_scan)

    def align_scan(self, scan: PreparedScan, T_initial: np.ndarray) -> Alignment:
        """Refine ``T_map_scan`` of a prepared scan from ``T_initial`` against the map."""
        return self.align(self.cloud(scan), T_initial)

    def insert(self, scan: AlignmentCloud, T_map_scan: np.ndarray) -> None:
        """Add an aligned scan at its pose ``T_map_scan`` (also advances the LRU clock)."""
        if len(scan) == 0:
            return
        self.settle()
        self._map.insert(scan.cloud, np.asarray(T_map_scan, dtype=np.float64))
        self._indexed = None
        self._gaussians = None
        self.insertions += 1
        self._version += 1

    def align(self, scan: AlignmentCloud, T_initial: np.ndarray) -> Alignment:
        """Refine ``T_map_scan`` from ``T_initial`` against the map."""
        if len(scan) < 6 or len(self) == 0:
            return _failed(T_initial, len(scan))
        init = np.asarray(T_initial, dtype=np.float64)
        common = _solver_settings(self.fine)
        if isinstance(self._map, small_gicp.GaussianVoxelMap):
            result = small_gicp.align(self._map, scan.cloud, init, **common)
        else:
            if self._indexed is None:
                self._indexed = AlignmentCloud.build(self.points(), 0.0, self.fine.num_neighbors)
            result = small_gicp.align(
                self._indexed.cloud,
                scan.cloud,
                self._indexed.tree,
                init,
                registration_type=_REGISTRATION_TYPES[self.fine.method],
                **common,
            )
        return _alignment(result, init, len(scan))


def voxel_gaussians(voxels: small_gicp.GaussianVoxelMap) -> Gaussians:
    """
    Return the means (V, 3) and covariances (V, 3, 3) of a Gaussian voxel map's voxels.

    Contiguous, as the sweep alignment's kernels take them (copied here).
    """
    means = np.asarray(voxels.voxel_points(), dtype=np.float64)[:, :3]
    covariances = np.asarray(voxels.voxel_covs(), dtype=np.float64).reshape(-1, 4, 4)
    return np.ascontiguousarray(means), np.ascontiguousarray(covariances[:, :3, :3])


def make_map(config: RegistrationConfig) -> LocalMap:
    """Return the map backend of the odometry (the seam of a keyframe store)."""
    return LocalMap(config.fine, config.local_map)


@dataclass
class Keyframe:
    """The scan others are registered onto: raw arrays (to re-prepare), prepared scan, pose."""

    index: int  # frame counter of the keyframe scan
    stamp_ns: int
    points: np.ndarray  # (N, 3) raw scan
    labels: np.ndarray  # (N,) raw labels (may be given as a Deferred: core/deferred.py)
    prepared: PreparedScan
    pose: np.ndarray  # (4, 4) T_odom_keyframe
    #: its own frame covariance when accepted (its axes; None: unknown), and its fine
    #: alignment's residual variance: ``covariance.keyframe_share`` (docs/covariance.md)
    frame_covariance: np.ndarray | None = None
    residual_variance: float = 0.0


deferred_attribute(Keyframe, 'labels')


def is_new_keyframe(policy: KeyframeConfig, T_keyframe_current: np.ndarray) -> bool:
    """Whether a scan accepted with this relative transform becomes the keyframe."""
    if policy.policy == 'every_frame':
        return True
    T = np.asarray(T_keyframe_current, dtype=np.float64)
    return (
        float(np.linalg.norm(T[:3, 3])) >= policy.min_distance
        or rotation_angle_deg(T) >= policy.min_rotation
    )


def insert_accepted(
    local_map: LocalMap,
    config: RegistrationConfig,
    keyframe: Keyframe,
    relative: np.ndarray,
    index: int,
    stamp_ns: int,
    raw: Any,
    pose: np.ndarray,
) -> tuple[Keyframe, int]:
    """
    Insert an accepted, aligned scan into the map and apply the keyframe policy.

    ``raw``: the :class:`~mlsemreg_ros.core.odometry.preprocess.PreprocessedScan` at
    ``pose`` (``T_odom_current``), ``relative`` to ``keyframe``. Returns the keyframe after
    it (this scan when the policy makes it one) and the map's occupied voxels.
    """
    local_map.insert_scan(raw.scan, pose)
    if is_new_keyframe(config.keyframe, relative) and not keyframe_refusal(config, raw.scan):
        labels = stored(raw, 'labels')
        keyframe = Keyframe(index, stamp_ns, raw.points, labels, raw.scan, pose.copy())
    return keyframe, len(local_map)


def keyframe_refusal(config: RegistrationConfig, scan: PreparedScan) -> str:
    """
    Why ``scan`` cannot be a keyframe ('' if it can).

    Too few points (``keyframe.min_points``), too few keypoints (``keyframe.min_keypoints``),
    or too little structure for the fine alignment (``keyframe.min_structure``,
    :func:`structure_ratio`): every later scan would fail against it.
    """
    policy = config.keyframe
    needed = min(policy.min_keypoints, config.keypoints.count)
    points, keypoints = len(scan.points), len(scan.keypoints)
    if points < policy.min_points or keypoints < needed:
        return (
            f'{points} points / {keypoints} keypoints < keyframe.min_points='
            f'{policy.min_points} / keyframe.min_keypoints={needed}'
        )
    if policy.min_structure > 0 and config.fine.method != 'off':
        ratio, weak = structure_ratio(alignment_cloud(scan, config.fine))
        if ratio < policy.min_structure:
            x, y, z = weak
            return (
                f'too little structure: translation along ({x:+.2f}, {y:+.2f}, {z:+.2f}) '
                f'constrained {ratio:.2g} as well as the best direction < '
                f'keyframe.min_structure={policy.min_structure:g}'
            )
    return ''


#: The plane-regularised covariance small_gicp gives each point: eigenvalues (eps, 1, 1).
_PLANE_EPSILON = 1e-3


def structure_ratio(cloud: AlignmentCloud) -> tuple[float, np.ndarray]:
    """
    How well the fine alignment can pin a scan: weakest over strongest translation direction.

    The translation block of the GICP Hessian of the scan aligned onto itself at the
    identity (each point its own correspondence, combined covariance ``2 C``), with
    small_gicp's plane-regularised covariances ``C = eps n n^T + (I - n n^T)``:
    ``H_t = sum inv(2 C) = 0.5 ((1/eps - 1) sum n n^T + N I)``. Returns the ratio of its
    smallest to its largest eigenvalue (0: unconstrained along some direction, 1: all
    alike) and the weakest direction (scan frame). Fewer than 6 points: (0, x axis).
    """
    if len(cloud) < 6:
        return 0.0, np.array([1.0, 0.0, 0.0])
    normals = np.asarray(cloud.cloud.normals(), dtype=np.float64)[:, :3]
    normals = normals[np.all(np.isfinite(normals), axis=1)]
    H = (1.0 / _PLANE_EPSILON - 1.0) * (normals.T @ normals) + len(normals) * np.eye(3)
    values, vectors = np.linalg.eigh(0.5 * H)
    weak = vectors[:, 0] * (1.0 if vectors[np.argmax(np.abs(vectors[:, 0])), 0] >= 0 else -1.0)
    return (float(values[0] / values[-1]) if values[-1] > 0 else 0.0), weak

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
Fine alignment of dense scans with small_gicp: scan to scan (pairs) and scan to local map.

The global estimate (ML-SemReg + SC2-PCR) is right to a few decimetres and tenths of a
degree; GICP (Segal et al., RSS 2009) / VGICP (Koide et al., ICRA 2021), as implemented
in koide3/small_gicp, take it to the precision of the dense scans. small_gicp does the
work (voxel grid, KD-tree, covariances, Gauss-Newton, voxel maps with an LRU horizon);
this module only chooses its inputs and reads its result:

    AlignmentCloud.build(points, res)    downsample, KD-tree, normals and covariances, once
    align_pair(source, target, T_init)   T_target_source refined scan to scan

The local map of the odometry (``core/odometry/local_map.py``) aligns with the same
solver settings.

Covariance (:meth:`Alignment.covariance`): small_gicp's Gauss-Newton Hessian ``H`` is in
the source frame, perturbation ``T exp(delta)``, ``delta = [omega, v]`` (checked by a
test on a corridor). ``inv(H)`` is scaled by the residual variance ``2 E / (n - 6)``
(``E`` final error, ``n`` inliers) and by a calibration factor, reordered to ROS's
``[x, y, z, roll, pitch, yaw]`` and rotated into the target frame's axes.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core import threads  # before small_gicp: sets OMP_WAIT_POLICY
from mlsemreg_ros.core.alignment.config import FineAlignmentConfig
import numpy as np
import small_gicp

#: small_gicp's name of each point-based method.
_REGISTRATION_TYPES = {'gicp': 'GICP', 'plane_icp': 'PLANE_ICP', 'icp': 'ICP'}


@dataclass
class AlignmentCloud:
    """One scan as small_gicp aligns it: downsampled points with normals, covariances, tree."""

    cloud: small_gicp.PointCloud
    tree: small_gicp.KdTree

    @classmethod
    def build(
        cls,
        points: np.ndarray,
        resolution: float = 0.0,
        num_neighbors: int = 10,
        num_threads: int | None = None,
    ) -> AlignmentCloud:
        """
        Downsample ``points`` (N, 3) to ``resolution`` metres, estimate local features.

        With resolution 0 the points are used as they are (they are voxelized already).
        Normals and covariances from ``num_neighbors`` neighbours. ``num_threads``
        (the KD-tree and the covariances, each point's own result whatever the count)
        defaults to :func:`threads.workers`; 1 inside a pool task. The downsampling runs
        on :data:`DETERMINISTIC_THREADS`.
        """
        points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        n = num_threads or threads.workers()
        if resolution > 0 and points.shape[0]:
            # one thread: the OpenMP sampling's point count and order vary run to run
            cloud = small_gicp.voxelgrid_sampling(points, resolution, DETERMINISTIC_THREADS)
        else:
            cloud = small_gicp.PointCloud(points)
        tree = small_gicp.KdTree(cloud, n)
        if cloud.size() > 0:
            small_gicp.estimate_normals_covariances(cloud, tree, num_neighbors, n)
        return cls(cloud, tree)

    def __len__(self) -> int:
        return int(self.cloud.size())

    @property
    def points(self) -> np.ndarray:
        """Return the coordinates (M, 3) of the alignment cloud, metres."""
        return self.cloud.points()[:, :3]


@dataclass
class Alignment:
    """What one fine alignment produced (small_gicp's RegistrationResult, named)."""

    T_target_source: np.ndarray  # (4, 4) refined: p_target = T @ p_source
    T_initial: np.ndarray  # (4, 4) the initial guess
    converged: bool
    iterations: int
    num_inliers: int  # source points with a correspondence within the distance bound
    num_points: int  # source points aligned
    error: float  # final cost E = sum of 0.5 r^T M r over the inliers
    hessian: np.ndarray  # (6, 6) Gauss-Newton H, source frame, order [omega, v]

    @property
    def inlier_fraction(self) -> float:
        """Share of the source points with a correspondence after the alignment."""
        return self.num_inliers / self.num_points if self.num_points else 0.0

    @property
    def residual_variance(self) -> float:
        """
        ``2E / (n - 6)``: the mean squared Mahalanobis residual per inlier (0: unknown).

        The variance that scales ``inv(H)`` in :meth:`covariance`; the calibration's floors
        read it apart too (``covariance.residual_*``, docs/covariance.md): a scan that fits
        its map tighter than usual is closer than the floors say.
        """
        dof = self.num_inliers - 6
        return 2.0 * self.error / dof if dof > 0 and np.isfinite(self.error) else 0.0

    @property
    def correction(self) -> np.ndarray:
        """``inv(T_initial) @ T_target_source``: how far the alignment moved its guess."""
        return np.linalg.solve(self.T_initial, self.T_target_source)

    def covariance(self, scale: float = 1.0, axes: str = 'target') -> np.ndarray:
        """
        Covariance (6, 6) of the refined pose, ROS order ``[x, y, z, roll, pitch, yaw]``.

        ``inv(H) * 2E / (n - 6) * scale`` in m^2 and rad^2. ``axes='target'`` rotates the
        perturbation into the target frame's axes (``delta_target = R delta_source`` for
        both parts; the pose covariance of nav_msgs/Odometry); ``'source'`` keeps the
        source (body) axes (the twist's). A singular Hessian (too few inliers) gives a
        large isotropic covariance.
        """
        dof = self.num_inliers - 6
        if dof <= 0 or not np.all(np.isfinite(self.hessian)):
            return np.eye(6) * UNKNOWN_VARIANCE
        variance = 2.0 * self.error / dof * scale
        try:
            body = np.linalg.inv(self.hessian) * variance
        except np.linalg.LinAlgError:
            return np.eye(6) * UNKNOWN_VARIANCE
        order = [3, 4, 5, 0, 1, 2]  # [omega, v] -> [v, omega]
        body = body[np.ix_(order, order)]
        if axes == 'source':
            return 0.5 * (body + body.T)
        rotation = np.zeros((6, 6))
        rotation[:3, :3] = rotation[3:, 3:] = self.T_target_source[:3, :3]
        covariance = rotation @ body @ rotation.T
        return 0.5 * (covariance + covariance.T)


#: Variance (m^2, rad^2) reported when an alignment cannot tell its own uncertainty.
UNKNOWN_VARIANCE = 1e6


#: small_gicp's thread count where its OpenMP result depends on the thread timing. Its
#: Gauss-Newton sums each thread's share of the factors (``schedule(guided)``: which
#: thread gets which factors changes run to run) and then adds the shares, so the
#: Hessian's last bits change with the timing and the thread count; its parallel voxel
#: sampling collects the voxels in completion order (the count and order vary). Last-bit
#: changes grow through the iterations and the acceptance tests: on the handheld VLP-16
#: walk, runs of the same input differed from the 6th scan on, by up to 5 cm (docs/sensors.md).
#: One thread makes both a function of the input alone.
DETERMINISTIC_THREADS = 1


def _solver_settings(cfg: FineAlignmentConfig) -> dict[str, float]:
    """Keyword arguments of ``small_gicp.align`` shared by every method."""
    return {
        'max_correspondence_distance': cfg.max_correspondence_distance,
        'num_threads': DETERMINISTIC_THREADS,
        'max_iterations': cfg.max_iterations,
        'rotation_epsilon': float(np.radians(cfg.rotation_epsilon)),
        'translation_epsilon': cfg.translation_epsilon,
    }


def _alignment(
    result: small_gicp.RegistrationResult, T_initial: np.ndarray, num_points: int
) -> Alignment:
    return Alignment(
        np.asarray(result.T_target_source, dtype=np.float64).copy(),
        np.asarray(T_initial, dtype=np.float64).copy(),
        bool(result.converged),
        int(result.iterations),
        int(result.num_inliers),
        int(num_points),
        float(result.error),
        np.asarray(result.H, dtype=np.float64).copy(),
    )


def _failed(T_initial: np.ndarray, num_points: int) -> Alignment:
    """Return an alignment that could not run (empty cloud): no inliers, guess unchanged."""
    T = np.asarray(T_initial, dtype=np.float64)
    return Alignment(T.copy(), T.copy(), False, 0, 0, num_points, 0.0, np.zeros((6, 6)))


def align_pair(
    source: AlignmentCloud,
    target: AlignmentCloud,
    T_initial: np.ndarray,
    cfg: FineAlignmentConfig,
    method: str | None = None,
) -> Alignment:
    """
    Refine ``T_target_source`` of two scans from ``T_initial``.

    ``method`` (default ``cfg.pair_method``): VGICP builds a Gaussian voxel map
    (``cfg.voxel_size``) of the target; the point-based methods use the target's KD-tree.
    ``'off'`` is not an alignment: callers skip the stage.
    """
    method = method or cfg.pair_method
    if len(source) < 6 or len(target) < 6:
        return _failed(T_initial, len(source))
    common = _solver_settings(cfg)
    init = np.asarray(T_initial, dtype=np.float64)
    if method == 'vgicp':
        voxels = small_gicp.GaussianVoxelMap(cfg.voxel_size)
        voxels.insert(target.cloud)
        result = small_gicp.align(voxels, source.cloud, init, **common)
    else:
        result = small_gicp.align(
            target.cloud,
            source.cloud,
            target.tree,
            init,
            registration_type=_REGISTRATION_TYPES[method],
            **common,
        )
    return _alignment(result, init, len(source))

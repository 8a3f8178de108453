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
Continuous-time sweep alignment: the pose at the stamp *and* the motion within the sweep.

Without a gyro, the deskew (``core/features/deskew.py``) takes the motion within a sweep
from the accepted poses: a constant twist over the last ``preprocess.deskew_window``
periods. When a turn starts or ends, the sweep's own yaw rate differs from that average,
the scan is bent by the difference, and the rigid alignment of a bent scan lands up to
0.7 m off (docs/field.md). Like CT-ICP (Dellenbach et al., ICRA 2022), this step
estimates the motion within the sweep from the sweep itself, jointly with the pose.

The model: a raw point ``p_i`` taken ``tau_i`` seconds after the stamp is, in the odom
frame, ``T exp(tau_i xi) p_i`` with ``T`` the pose at the stamp and ``xi = (omega, v)``
the sweep's constant twist (the deskew's :class:`SweepMotion`). Gauss-Newton minimises

    sum_i rho(e_i^T Omega_i e_i) + |omega - omega_0|^2 / s_w^2 + |v - v_0|^2 / s_v^2
          + |log(T_0^-1 T)|^2 (weak, for the directions the scene leaves free)

with ``e_i`` the offset of the point from the Gaussian of its nearest map voxel (mean
``mu``, covariance ``C``, ``Omega = (C + eps I)^-1``: the point-to-distribution cost of
NDT / VGICP, the local map's own Gaussians) and ``rho`` Geman-McClure. The twist's prior
is the deskew's twist ``xi_0``: where the scene does not constrain the motion within the
sweep (forward speed in a straight street), the deskew's value stays. The perturbations
are ``T exp(delta)`` and ``xi + delta_xi``; to first order

    de/d(delta_phi, delta_t) = R [-[d]x, I],  de/d(delta_omega, delta_v) = tau R [-[d]x, I]

with ``d = exp(tau xi) p`` the deskewed point. Every step is vectorised over the points
(every k-th point, about ``sweep_alignment.points``); the map's nearest voxels come from
the means sorted by cells of ``max_distance`` (``core/features/cell_grid.py``, the search the
dense scores use too).
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core import threads
from mlsemreg_ros.core.alignment import sweep_kernels
from mlsemreg_ros.core.alignment.config import SweepAlignmentConfig
from mlsemreg_ros.core.features import kernels
from mlsemreg_ros.core.features.cell_grid import CellGrid
from mlsemreg_ros.core.features.deskew import _twist_terms, deskew, SMALL_ANGLE, SweepMotion
import numpy as np
import small_gicp

#: Added to every map voxel's covariance (m^2): a voxel of a few points is not a plane of 0 m.
VOXEL_REGULARIZATION = 0.01
#: Weak prior on the pose correction: rotation (rad) and translation (m) standard deviations.
POSE_PRIOR_SIGMA = (0.05, 0.5)
#: Geman-McClure scale (squared Mahalanobis distance) of the first step; it falls
#: geometrically to 1 (a voxel's spread) at the second-to-last step (halving at every step
#: with the default 8 steps): a bent sweep's far points still pull at first.
KERNEL_SCALE_START = 64.0
#: Gauss-Newton stops when the update is below this (rad, m, rad/s, m/s).
STEP_TOLERANCE = 1e-4


@dataclass(frozen=True)
class SweepAlignment:
    """The result: pose at the stamp, twist within the sweep, and what the data said."""

    T_target_source: np.ndarray  # (4, 4) T_odom_stamp
    motion: SweepMotion
    change_m: float  # largest point move of the new twist against the initial one
    pairs: int  # points with a map voxel at the last step
    iterations: int

    def summary(self, initial: SweepMotion) -> str:
        """One line: the yaw rate before and after, and the bend."""
        before, after = np.degrees(initial.omega[2]), np.degrees(self.motion.omega[2])
        return (
            f'sweep alignment: yaw rate {before:.1f} -> {after:.1f} deg/s, '
            f'bend {100 * self.change_m:.1f} cm'
        )


class MapGaussians:
    """
    A local map's voxel Gaussians and a search of the nearest mean (built once per use).

    With the compiled kernels, the means are sorted by cells of the search distance
    (:class:`~mlsemreg_ros.core.features.cell_grid.CellGrid`: built in one pass, exact
    within that distance); without them, for an unbounded search, or for a map the cells
    cannot hold, small_gicp's KD-tree.
    """

    def __init__(self, means: np.ndarray, covariances: np.ndarray) -> None:
        """``means`` (V, 3) and ``covariances`` (V, 3, 3) in the map frame."""
        self.means = np.ascontiguousarray(means[:, :3], dtype=np.float64)
        self.covariances = np.asarray(covariances, dtype=np.float64)[:, :3, :3]
        self._tree: small_gicp.KdTree | None = None
        self._cells: CellGrid | None = None

    def __len__(self) -> int:
        """Voxels."""
        return len(self.means)

    def cells(self, cell: float) -> CellGrid | None:
        """Return the means sorted by cells of edge ``cell`` (built once; None: unusable)."""
        if self._cells is None or self._cells.cell != cell:
            self._cells = CellGrid.build(self.means, cell)
        return self._cells if self._cells.usable else None

    def kernel_map(self, cells: CellGrid, max_distance: float) -> sweep_kernels.SweepMap:
        """Return the map for the compiled sweep kernels, pairing within ``max_distance``."""
        return sweep_kernels.SweepMap.of(
            cells, self.means, self.covariances, max_distance, VOXEL_REGULARIZATION
        )

    def nearest(
        self, points: np.ndarray, within: float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """
        Index and squared distance of each point's nearest mean.

        ``within``: only a mean at most this far counts; a point without one may then get
        index -1 and an infinite squared distance (the hashed search). None: any distance.
        """
        cells = (
            self.cells(within) if within is not None and within > 0 and kernels.enabled() else None
        )
        if cells is not None:
            squared, index = cells.nearest_squared(points, within)
            return index, squared
        if self._tree is None:
            self._tree = small_gicp.KdTree(self.means, num_threads=threads.workers())
        index, sq = self._tree.batch_nearest_neighbor_search(
            np.ascontiguousarray(points), num_threads=threads.workers()
        )
        return np.asarray(index, dtype=np.int64), np.asarray(sq, dtype=np.float64)


def sweep_subset(
    points: np.ndarray, times: np.ndarray, count: int
) -> tuple[np.ndarray, np.ndarray]:
    """Return about ``count`` points with their times: every k-th (a sweep is column-ordered)."""
    step = max(1, len(points) // max(count, 1))
    return (
        np.ascontiguousarray(points[::step], dtype=np.float64),
        np.ascontiguousarray(times[::step], dtype=np.float64),
    )


def align_sweep(
    points: np.ndarray,
    times: np.ndarray,
    gaussians: MapGaussians,
    T_initial: np.ndarray,
    motion_initial: SweepMotion,
    config: SweepAlignmentConfig,
    compiled: bool | None = None,
) -> SweepAlignment:
    """
    Estimate the pose at the stamp and the sweep twist of raw ``points`` taken at ``times``.

    ``points`` (N, 3) as the sensor gave them, ``times`` (N,) s after the stamp,
    ``T_initial`` the rigid alignment of the scan deskewed by ``motion_initial``.
    ``compiled``: the whole loop in one compiled call (``sweep_kernels.align_sweep``; None:
    when the kernels are on and the map's cells are usable), else this loop, each step's
    linearization compiled or not (:func:`linearization`).
    """
    T = np.asarray(T_initial, dtype=np.float64).copy()
    xi0 = np.concatenate([motion_initial.omega, motion_initial.velocity]).astype(np.float64)
    xi = xi0.copy()
    sigma_r, sigma_t = POSE_PRIOR_SIGMA
    prior = np.concatenate(
        [
            np.full(3, 1.0 / sigma_r**2),
            np.full(3, 1.0 / sigma_t**2),
            np.full(3, 1.0 / config.rate_sigma**2),
            np.full(3, 1.0 / config.velocity_sigma**2),
        ]
    )
    cells = gaussians.cells(config.max_distance) if kernels.use_compiled(compiled) else None
    if cells is not None:
        schedule = sweep_kernels.SweepSchedule(
            config.iterations, KERNEL_SCALE_START, STEP_TOLERANCE, SMALL_ANGLE
        )
        local_map = gaussians.kernel_map(cells, config.max_distance)
        T, xi, pairs, iteration, change_m = sweep_kernels.align_sweep(
            points, times, T, xi0, prior, schedule, local_map
        )
        return SweepAlignment(T, SweepMotion(xi[:3], xi[3:]), change_m, pairs, iteration)
    pose_offset = np.zeros(6)  # accumulated (phi, t) of T relative to T_initial
    pairs, iteration = 0, 0
    decay = KERNEL_SCALE_START ** (-1.0 / max(config.iterations - 2, 1))
    for iteration in range(1, config.iterations + 1):
        scale = max(1.0, KERNEL_SCALE_START * decay ** (iteration - 1))
        hessian, gradient, pairs = linearization(
            points, times, SweepMotion(xi[:3], xi[3:]), T, gaussians, config.max_distance, scale
        )
        if pairs < 12:
            break
        state = np.concatenate([pose_offset, xi - xi0])
        hessian[np.diag_indices(12)] += prior
        gradient += prior * state
        try:
            step = -np.linalg.solve(hessian, gradient)
        except np.linalg.LinAlgError:
            break
        T = T @ _se3_small(step[:6])
        pose_offset = pose_offset + step[:6]
        xi = xi + step[6:]
        if float(np.max(np.abs(step))) < STEP_TOLERANCE:
            break
    motion = SweepMotion(xi[:3], xi[3:])
    change = deskew(points, times, motion) - deskew(points, times, motion_initial)
    change_m = float(np.sqrt(np.max(np.einsum('ni,ni->n', change, change), initial=0.0)))
    return SweepAlignment(T, motion, change_m, pairs, iteration)


def linearization(
    points: np.ndarray,
    times: np.ndarray,
    motion: SweepMotion,
    T: np.ndarray,
    gaussians: MapGaussians,
    max_distance: float,
    scale: float,
) -> tuple[np.ndarray, np.ndarray, int]:
    """
    ``H``, ``g`` and the pair count of the points deskewed by ``motion`` and moved by ``T``.

    Each point pairs with its nearest map mean within ``max_distance``. Compiled in one pass
    (``sweep_kernels.sweep_linearization``) when the kernels are on; else the NumPy steps.
    """
    cells = gaussians.cells(max_distance) if kernels.enabled() else None
    if cells is not None:
        local_map = gaussians.kernel_map(cells, max_distance)
        return sweep_kernels.sweep_linearization(
            points, times, _twist_terms(motion), SMALL_ANGLE, T, local_map, scale
        )
    deskewed = deskew(points, times, motion)
    world = deskewed @ T[:3, :3].T + T[:3, 3]
    index, sq = gaussians.nearest(world, max_distance)
    keep = sq < max_distance**2
    pairs = int(np.count_nonzero(keep))
    if pairs < 12:
        return np.zeros((12, 12)), np.zeros(12), pairs
    j = index[keep]
    hessian, gradient = normal_equations(
        deskewed[keep],
        times[keep],
        world[keep] - gaussians.means[j],
        gaussians.covariances[j],
        T[:3, :3],
        scale,
    )
    return hessian, gradient, pairs


def normal_equations(
    deskewed: np.ndarray,
    tau: np.ndarray,
    offset: np.ndarray,
    covariances: np.ndarray,
    rotation: np.ndarray,
    scale: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Return ``H`` and ``g`` of the paired points: compiled when the kernels are on."""
    if kernels.enabled():
        return sweep_kernels.normal_equations(
            deskewed, tau, offset, covariances, rotation, VOXEL_REGULARIZATION, scale
        )
    information = np.linalg.inv(covariances + VOXEL_REGULARIZATION * np.eye(3))
    return normal_equations_numpy(deskewed, tau, offset, information, rotation, scale)


def normal_equations_numpy(
    deskewed: np.ndarray,
    tau: np.ndarray,
    offset: np.ndarray,
    information: np.ndarray,
    rotation: np.ndarray,
    scale: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """
    Return the Gauss-Newton ``H`` (12, 12) and ``g`` (12,) of the paired points (NumPy).

    Per point, in the stamp frame: ``e = R^T offset``, ``A = w R^T Omega R`` (Geman-McClure
    weight ``w`` on ``e^T A e``), ``G = [-[d]x, I]`` (3, 6); the 12 columns are ``G`` and
    ``tau G``, so ``H = sum [[B, tau B], [tau B, tau^2 B]]`` with ``B = G^T A G`` (6, 6).
    """
    error = offset @ rotation  # (n, 3): R^T e
    info = np.matmul(np.matmul(rotation.T[None], information), rotation[None])
    mahalanobis = np.einsum('ni,nij,nj->n', error, info, error)
    weight = (scale / (scale + mahalanobis)) ** 2  # Geman-McClure
    info *= weight[:, None, None]
    jacobian = np.empty((len(deskewed), 3, 6))
    jacobian[:, :, :3] = _skew_batch(-deskewed)
    jacobian[:, :, 3:] = np.eye(3)
    jt_a = np.matmul(jacobian.transpose(0, 2, 1), info)  # (n, 6, 3)
    block = np.matmul(jt_a, jacobian)  # (n, 6, 6)
    grad = np.matmul(jt_a, error[:, :, None])[:, :, 0]  # (n, 6)
    flat = block.reshape(len(block), 36)
    sums = np.stack([tau**0, tau, tau**2]) @ flat  # (3, 36)
    b0, b1, b2 = (x.reshape(6, 6) for x in sums)
    hessian = np.block([[b0, b1], [b1, b2]])
    g0, g1 = np.stack([tau**0, tau]) @ grad
    return hessian, np.concatenate([g0, g1])


def _skew_batch(vectors: np.ndarray) -> np.ndarray:
    """Return the skew-symmetric matrices (N, 3, 3) of ``vectors`` (N, 3)."""
    out = np.zeros((len(vectors), 3, 3))
    x, y, z = vectors[:, 0], vectors[:, 1], vectors[:, 2]
    out[:, 0, 1], out[:, 0, 2] = -z, y
    out[:, 1, 0], out[:, 1, 2] = z, -x
    out[:, 2, 0], out[:, 2, 1] = -y, x
    return out


def _se3_small(step: np.ndarray) -> np.ndarray:
    """Return the (4, 4) pose of a small step ``(phi, t)``: rotation exact, translation as is."""
    out = np.eye(4)
    phi = np.asarray(step[:3], dtype=np.float64)
    angle = float(np.sqrt(phi @ phi))
    if angle > 0.0:  # Rodrigues (scipy's Rotation costs ten times as much on one vector)
        k = phi / angle
        skew = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        out[:3, :3] += np.sin(angle) * skew + (1.0 - np.cos(angle)) * (skew @ skew)
    out[:3, 3] = step[3:]
    return out

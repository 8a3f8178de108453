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
Rigid transforms from point correspondences: batched weighted Kabsch (SVD).

Conventions: a transform ``T`` is a ``(4, 4)`` homogeneous matrix with
``p_target = T @ p_source``; point sets are ``(..., K, 3)`` arrays in metres.
"""

from __future__ import annotations

import math

import numpy as np

#: A batch whose weights sum to at most this is solved with uniform weights.
_MIN_WEIGHT_SUM = 1e-12


def weighted_rigid_transform(
    src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None
) -> np.ndarray:
    """
    Least-squares rigid transform mapping ``src`` onto ``dst`` (weighted Kabsch).

    Minimises ``sum_i w_i ||R src_i + t - dst_i||^2`` over rotations ``R`` and
    translations ``t`` by the SVD of the weighted cross-covariance, with the
    reflection fix ``diag(1, 1, det(V U^T))`` so ``det(R) = +1``.  This is the
    weighted SVD SC2-PCR (Chen et al., CVPR 2022) runs per seed and in its
    post-refinement.

    - ``src``: ``(..., K, 3)`` source points.
    - ``dst``: ``(..., K, 3)`` target points, row ``i`` paired with ``src[..., i, :]``.
    - ``weights``: ``(..., K)`` non-negative weights, or None for uniform weights.
      A batch element whose weights sum to (almost) zero falls back to
      uniform weights, so the result is always finite for finite input.

    Returns ``(..., 4, 4)`` float64 transforms ``T_dst_src``.  With fewer than three
    non-collinear points the rotation is not unique; the SVD then picks one (identity for a
    single point).
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim < 2 or src.shape[-1] != 3:
        raise ValueError(f'src and dst must both be (..., K, 3), got {src.shape} and {dst.shape}')
    batch, count = src.shape[:-2], src.shape[-2]
    out = np.broadcast_to(np.eye(4), (*batch, 4, 4)).copy()
    if count == 0:
        return out
    if weights is None:
        w = np.ones(src.shape[:-1])
    else:
        w = np.clip(np.asarray(weights, dtype=np.float64), 0.0, None)
        if w.shape != src.shape[:-1]:
            raise ValueError(f'weights must be {src.shape[:-1]}, got {w.shape}')
    total = w.sum(axis=-1, keepdims=True)
    degenerate = total <= _MIN_WEIGHT_SUM
    w = np.where(degenerate, 1.0 / count, w / np.where(degenerate, 1.0, total))
    centroid_src = np.einsum('...k,...kd->...d', w, src)
    centroid_dst = np.einsum('...k,...kd->...d', w, dst)
    src_c = src - centroid_src[..., None, :]
    dst_c = dst - centroid_dst[..., None, :]
    cov = np.swapaxes(src_c * w[..., None], -1, -2) @ dst_c  # H = A^T W B
    u, _, vt = np.linalg.svd(cov)
    v_ut = np.swapaxes(vt, -1, -2) @ np.swapaxes(u, -1, -2)
    fix = np.broadcast_to(np.eye(3), (*batch, 3, 3)).copy()
    fix[..., 2, 2] = np.where(np.linalg.det(v_ut) < 0.0, -1.0, 1.0)  # no reflection
    rotation = np.swapaxes(vt, -1, -2) @ fix @ np.swapaxes(u, -1, -2)
    out[..., :3, :3] = rotation
    out[..., :3, 3] = centroid_dst - np.einsum('...ij,...j->...i', rotation, centroid_src)
    return out


def apply_transform(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """
    Apply ``(..., 4, 4)`` transforms to ``(..., K, 3)`` points: ``R p + t``.

    Batch dimensions broadcast, e.g. ``(S, 4, 4)`` with ``(K, 3)`` gives ``(S, K, 3)``.
    """
    transform = np.asarray(transform)
    points = np.asarray(points)
    rotation = transform[..., :3, :3]
    translation = transform[..., None, :3, 3]
    return points @ np.swapaxes(rotation, -1, -2) + translation


def invert_transform(transform: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform ``(4, 4)`` or a stack ``(..., 4, 4)``: ``[R^T, -R^T t]``."""
    transform = np.asarray(transform, dtype=np.float64)
    rotation_t = np.swapaxes(transform[..., :3, :3], -1, -2)
    out = np.zeros_like(transform)
    out[..., :3, :3] = rotation_t
    out[..., :3, 3] = -np.einsum('...ij,...j->...i', rotation_t, transform[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def relative_transform(T_world_a: np.ndarray, T_world_b: np.ndarray) -> np.ndarray:
    """
    ``T_a_b = T_world_a^-1 T_world_b``: pose ``b`` seen from ``a`` (both ``(..., 4, 4)``).

    E.g. the ground truth of scan ``b`` registered onto keyframe ``a`` from their poses.
    """
    return invert_transform(T_world_a) @ np.asarray(T_world_b, dtype=np.float64)


def rotation_angle_deg(transform: np.ndarray) -> float:
    """Rotation angle of a transform (4, 4) or rotation (3, 3), degrees."""
    rotation = np.asarray(transform, dtype=np.float64)[:3, :3]
    cos = np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(cos)))


def scale_motion(motion: np.ndarray, factor: float) -> np.ndarray:
    """
    ``motion`` (4, 4) scaled in time: rotation vector and translation times ``factor``.

    The constant-velocity prediction of a motion observed over ``dt`` for ``factor * dt``
    (first order in the rotation: exact for pure rotations and pure translations).
    """
    out = np.eye(4)
    rotvec = rotation_vector(np.asarray(motion, dtype=np.float64)[:3, :3])
    out[:3, :3] = rotation_matrix(rotvec * factor)
    out[:3, 3] = np.asarray(motion, dtype=np.float64)[:3, 3] * factor
    return out


def rotation_vector(rotation: np.ndarray) -> np.ndarray:
    """
    Rotation vector (3,) of one rotation matrix (3, 3): SO(3)'s logarithm.

    SciPy's ``Rotation.from_matrix(R).as_rotvec()`` (the same quaternion by Shepperd's
    method, the same small-angle series, equal to rounding) on plain floats: the per-scan
    steps call it a few times on one matrix, where SciPy's array checks cost 0.2 ms a call.
    The matrix is taken as a rotation (not orthonormalised).
    """
    (a, b, c), (d, e, f), (g, h, i) = np.asarray(rotation, dtype=np.float64)[:3, :3].tolist()
    trace = a + e + i
    largest = max(a, e, i, trace)
    if largest == trace:
        w, x, y, z = 1.0 + trace, h - f, c - g, d - b
    elif largest == a:
        w, x, y, z = h - f, 1.0 + 2.0 * a - trace, d + b, c + g
    elif largest == e:
        w, x, y, z = c - g, d + b, 1.0 + 2.0 * e - trace, h + f
    else:
        w, x, y, z = d - b, c + g, h + f, 1.0 + 2.0 * i - trace
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        norm = -norm
    w, x, y, z = w / norm, x / norm, y / norm, z / norm
    angle = 2.0 * math.atan2(math.sqrt(x * x + y * y + z * z), w)
    if angle <= 1e-3:
        scale = 2.0 + angle**2 / 12.0 + 7.0 * angle**4 / 2880.0
    else:
        scale = angle / math.sin(0.5 * angle)
    return np.array([scale * x, scale * y, scale * z])


def rotation_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of one rotation vector (3,): SO(3)'s exponential (Rodrigues)."""
    x, y, z = np.asarray(rotvec, dtype=np.float64).reshape(3).tolist()
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < 1e-8:  # sin(t)/t and (1 - cos t)/t^2 to second order: exact to rounding
        k, q = 1.0 - angle**2 / 6.0, 0.5 - angle**2 / 24.0
    else:
        k, q = math.sin(angle) / angle, (1.0 - math.cos(angle)) / angle**2
    return np.array(
        [
            [1.0 - q * (y * y + z * z), q * x * y - k * z, q * x * z + k * y],
            [q * x * y + k * z, 1.0 - q * (x * x + z * z), q * y * z - k * x],
            [q * x * z - k * y, q * y * z + k * x, 1.0 - q * (x * x + y * y)],
        ]
    )

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
The calibrated pose covariance of a fine alignment (docs/covariance.md).

The fine alignment's Hessian gives ``C_H = inv(H) * 2E / (n - 6)``. Its residuals are not
independent (neighbouring points share a surface, the deskew and the map carry errors
of their own), so ``C_H`` claims too little. The calibrated covariance is

``C = s * C_H + D + diag(sigma_t(d, a)^2 I3, sigma_r(d, a)^2 I3)``

- ``s``: ``odometry.covariance_scale``;
- ``D``: the inflation along the degenerate directions of the Hessian: in the translation
  and the rotation block of ``s * C_H`` apart, every eigen-direction whose variance exceeds
  ``covariance.degenerate_ratio`` times the block's smallest gets
  ``covariance.degenerate_translation`` (m) or ``covariance.degenerate_rotation`` (deg)
  squared added along it (a corridor, a tunnel, a flat field: the Hessian sees one
  direction weakly, and the error there is larger than even the weak curvature says);
- ``sigma_t(d, a) = covariance.floor_translation + covariance.per_metre_translation * d
  + covariance.per_degree_translation * a`` and ``sigma_r(d, a)`` likewise (in deg), with
  ``d`` the distance and ``a`` the angle (deg) of the motion the covariance describes (the
  odometry: from the keyframe to the scan; a pair: between the scans): the errors no
  Hessian sees (deskew, timing, labels, the keyframe's and the local map's own drift),
  which grow with the distance and in turns; the rotation part is shaped like the
  Hessian's rotation block (``covariance.rotation_floor_shape``, :func:`floor_shape`): a
  rotation the scene observes worse (the roll on a straight road) gets more of it;
- plus ``covariance.per_correction_translation * max(k * c - correction_free_translation,
  0)`` (and the rotation likewise), ``c`` the distance of the accepted pose from the motion
  model's prediction and ``k = min(1, correction_sweep / horizon)`` the share of it that
  fell within one sweep (``horizon``: the time since the last accepted scan): the
  prediction deskewed the scan, and a velocity it got wrong bends the sweep.

The odometry applies it to every accepted scan's frame covariance
(``core/odometry/odometry.py``), so the pose covariance, the twist covariance and the
NEES of ``mlsemreg eval-bag`` use it. ``mlsemreg covariance-nees`` measures it.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core.settings import param
import numpy as np

#: The most a shaped floor (``covariance.rotation_floor_shape``) stretches one direction's
#: variance.
MAX_FLOOR_STRETCH = 100.0


@dataclass
class CovarianceConfig:
    """Calibration of the fine alignment's pose covariance (docs/covariance.md)."""

    floor_translation: float = param(
        0.018,
        'Standard deviation added to every axis of the pose covariance (errors the '
        'Hessian does not see: deskew, labels, the keyframe).',
        unit='m',
        low=0.0,
        high=100.0,
    )
    floor_rotation: float = param(
        0.02,
        'Standard deviation added to every rotation axis of the pose covariance.',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    per_metre_translation: float = param(
        0.002,
        'Standard deviation added to every translation axis per metre of the motion the '
        'covariance describes (from the keyframe to the scan).',
        unit='m/m',
        low=0.0,
        high=10.0,
    )
    per_metre_rotation: float = param(
        0.003,
        'Standard deviation added to every rotation axis per metre of that motion.',
        unit='deg/m',
        low=0.0,
        high=100.0,
    )
    per_degree_translation: float = param(
        0.004,
        'Standard deviation added to every translation axis per degree the motion turned '
        '(deskew and timing errors grow in turns).',
        unit='m/deg',
        low=0.0,
        high=10.0,
    )
    per_degree_rotation: float = param(
        0.007,
        'Standard deviation added to every rotation axis per degree the motion turned.',
        unit='deg/deg',
        low=0.0,
        high=10.0,
    )
    per_correction_translation: float = param(
        1.8,
        'Standard deviation added to every translation axis per metre that the accepted pose '
        "lies from the motion model's prediction (times the sweep share, correction_sweep) "
        'beyond correction_free_translation: the scan was deskewed by that prediction, so a '
        'turn the prediction missed bends it (field drives at stride 1: scans 0.2-0.55 m '
        'from their prediction were 16-27 cm off). 0: off (docs/covariance.md).',
        unit='m/m',
        low=0.0,
        high=10.0,
    )
    per_correction_rotation: float = param(
        0.44,
        'Standard deviation added to every rotation axis per degree that the accepted pose '
        'turned from the prediction (times the sweep share) beyond correction_free_rotation. '
        '0: off.',
        unit='deg/deg',
        low=0.0,
        high=10.0,
    )
    correction_free_translation: float = param(
        0.36,
        'The part of the distance from the prediction (times the sweep share) that adds '
        'nothing (per_correction_translation).',
        unit='m',
        low=0.0,
        high=100.0,
    )
    correction_free_rotation: float = param(
        0.2,
        'The part of the turn from the prediction that adds nothing (per_correction_rotation).',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    correction_sweep: float = param(
        0.135,
        "The sweep time over which the prediction's velocity error bends the scan: the "
        'correction counts times min(1, correction_sweep / horizon), the horizon being the '
        'time since the last accepted scan (a prediction 3 m off after 1 s bends a sweep as '
        'much as one 0.3 m off after 0.1 s). 0: the correction counts whole.',
        unit='s',
        low=0.0,
        high=10.0,
    )
    rotation_floor_shape: float = param(
        0.5,
        "The rotation floor follows the shape of the Hessian's rotation block: along each of "
        'its eigen-directions the floor variance is multiplied by (variance / geometric mean '
        'of the three) to this power, capped at 100 (the product stays 1). A roll the scene '
        'observes worse than the pitch (a straight road, the ground seen on one side) gets '
        'more of the floor. 0: isotropic (docs/covariance.md).',
        low=0.0,
        high=2.0,
    )
    degenerate_ratio: float = param(
        100.0,
        'An eigen-direction of the translation or rotation block of the Hessian covariance '
        'is degenerate when its variance exceeds this many times the smallest of its '
        'block (0: no inflation).',
        low=0.0,
        high=1e12,
    )
    degenerate_translation: float = param(
        0.5,
        'Standard deviation added along a degenerate translation direction.',
        unit='m',
        low=0.0,
        high=1000.0,
    )
    degenerate_rotation: float = param(
        2.0,
        'Standard deviation added along a degenerate rotation direction.',
        unit='deg',
        low=0.0,
        high=180.0,
    )


def no_calibration() -> CovarianceConfig:
    """Return the calibration that adds nothing (the Hessian covariance times the scale)."""
    return CovarianceConfig(**dict.fromkeys(CovarianceConfig.__dataclass_fields__, 0.0))


def degenerate_inflation(covariance: np.ndarray, cfg: CovarianceConfig) -> np.ndarray:
    """Return the inflation ``D`` (6, 6) of ``covariance`` (ROS order) along weak directions."""
    inflation = np.zeros((6, 6))
    if cfg.degenerate_ratio <= 0:
        return inflation
    sigmas = (cfg.degenerate_translation, np.radians(cfg.degenerate_rotation))
    for block, sigma in zip((slice(0, 3), slice(3, 6)), sigmas, strict=True):
        if sigma <= 0:
            continue
        values, vectors = np.linalg.eigh(covariance[block, block])
        weak = values > cfg.degenerate_ratio * max(values[0], 1e-300)
        if np.any(weak):
            directions = vectors[:, weak]
            inflation[block, block] = sigma**2 * directions @ directions.T
    return inflation


def calibrated_covariance(
    hessian_covariance: np.ndarray,
    scale: float,
    cfg: CovarianceConfig,
    distance: float = 0.0,
    turn_deg: float = 0.0,
    correction: tuple[float, float] = (0.0, 0.0),
    horizon_s: float = 0.0,
) -> np.ndarray:
    """
    Return ``s * C_H + D + floor(d)`` (module docstring) of a covariance (6, 6), ROS order.

    ``hessian_covariance``: ``inv(H) * 2E / (n - 6)`` (``scale`` 1) in either axes: the
    floor is isotropic and the inflation follows the eigen-directions, so the result
    rotates with the input. ``correction``: the distance (m) and angle (deg) between the
    accepted pose and the motion model's prediction (the ``per_correction_*`` terms);
    ``horizon_s``: the time the prediction spanned, from the last accepted scan (0: unknown,
    the correction counts whole).
    """
    scaled = np.asarray(hessian_covariance, dtype=np.float64) * scale
    moved_m, turned_deg = np.multiply(correction, sweep_share(horizon_s, cfg))
    sigma_t = (
        cfg.floor_translation
        + cfg.per_metre_translation * distance
        + cfg.per_degree_translation * turn_deg
        + cfg.per_correction_translation * max(moved_m - cfg.correction_free_translation, 0.0)
    )
    sigma_r = np.radians(
        cfg.floor_rotation
        + cfg.per_metre_rotation * distance
        + cfg.per_degree_rotation * turn_deg
        + cfg.per_correction_rotation * max(turned_deg - cfg.correction_free_rotation, 0.0)
    )
    floor = np.diag([sigma_t**2] * 3 + [0.0] * 3)
    floor[3:, 3:] = sigma_r**2 * floor_shape(scaled[3:, 3:], cfg.rotation_floor_shape)
    covariance = scaled + degenerate_inflation(scaled, cfg) + floor
    return 0.5 * (covariance + covariance.T)


def floor_shape(blocks: np.ndarray, exponent: float) -> np.ndarray:
    """
    Return the shape (..., 3, 3) of a floor that follows covariance ``blocks`` (..., 3, 3).

    ``U diag(w) U^T`` with ``U`` the blocks' eigen-directions and ``w = (lambda / g) ** exponent``,
    ``g`` the geometric mean of the eigenvalues ``lambda`` (so ``prod(w) = 1``: the floor's
    volume is kept, only its shape follows the Hessian), ``w`` at most
    ``MAX_FLOOR_STRETCH``. Exponent 0, or a block that is zero or not finite: the identity.
    """
    blocks = np.asarray(blocks, dtype=np.float64)
    identity = np.broadcast_to(np.eye(3), blocks.shape).copy()
    if exponent <= 0.0:
        return identity
    usable = np.all(np.isfinite(blocks), axis=(-2, -1))
    safe = np.where(usable[..., None, None], blocks, np.eye(3))
    values, vectors = np.linalg.eigh(0.5 * (safe + np.swapaxes(safe, -1, -2)))
    values = np.maximum(values, 1e-30)
    logs = np.log(values)
    weights = np.exp(exponent * (logs - logs.mean(axis=-1, keepdims=True)))
    weights = np.minimum(weights, MAX_FLOOR_STRETCH)
    shaped = np.einsum('...ij,...j,...kj->...ik', vectors, weights, vectors)
    usable &= np.any(blocks != 0.0, axis=(-2, -1))
    return np.where(usable[..., None, None], shaped, identity)


def sweep_share(horizon_s: float, cfg: CovarianceConfig) -> float:
    """Return ``min(1, correction_sweep / horizon)``: the share of a correction in the sweep."""
    if horizon_s <= 0.0 or cfg.correction_sweep <= 0.0:
        return 1.0
    return min(1.0, cfg.correction_sweep / horizon_s)


def motion_size(motion: np.ndarray) -> tuple[float, float]:
    """Return the distance (m) and the rotation angle (deg) of a motion (4, 4)."""
    cosine = np.clip((np.trace(motion[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.linalg.norm(motion[:3, 3])), float(np.degrees(np.arccos(cosine)))

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
  prediction deskewed the scan, and a velocity it got wrong bends the sweep;
- plus ``(covariance.along_correction * k * |c|)^2`` along the direction of that correction
  (:func:`along_correction`): the scan stays off along it;
- the sweep alignment's **bend** ``b`` (how far its twist moved the points of a scan it
  deskewed again, ``Decision.sweep_bend_m``): ``covariance.per_bend_translation`` and
  ``per_bend_rotation`` times ``max(k_b * b - bend_free, 0)`` (``k_b = min(1, bend_window /
  horizon)``) join the floors, and ``covariance.bend_relief`` takes that share off the
  correction terms of a bent scan (:func:`correction_relief`). Off by default: no fit found
  a setting that keeps every data set (docs/covariance.md, session 18);
- the fine alignment's **residual** ``r = 2E / (n - 6)`` (:attr:`Alignment.residual_variance`):
  the translation floor's variance (every term above) times ``(r / REFERENCE_RESIDUAL) **
  covariance.residual_translation_exponent`` (the rotation's likewise), within
  ``residual_min_factor`` and ``residual_max_factor``: a tracked scan that fits its map
  tighter than usual is closer than the floors say (docs/covariance.md, session 20);
- the **keyframe's** own frame covariance ``C_k``, times ``covariance.keyframe_share`` and
  rotated into the scan's axes (:func:`keyframe_covariances`), where the scan fits its map
  tightly (residual below ``keyframe_scan_residual``) and the keyframe fitted it
  ``keyframe_residual_ratio`` times looser: the pose is relative to the keyframe, and a
  misplaced keyframe carries its error into a scan that fits the map (session 21).

What differs between sensors is followed through the Hessian's own size, not a table per
sensor: ``covariance.hessian_size_exponent`` grows the scale of a block as its Hessian
covariance tightens (a dense scan's many residuals are correlated, so its Hessian
understates the error more), and ``covariance.floor_size_exponent`` grows the floors of a
block with it (a sparse scan drifts more per metre): :func:`follow_hessian_size`. The
translation floor can take the Hessian's shape too (``covariance.translation_floor_shape``).

The odometry applies it to every accepted scan's frame covariance
(``core/odometry/advance.py``), so the pose covariance, the twist covariance and the
NEES of ``mlsemreg eval-bag`` use it. ``mlsemreg covariance-nees`` measures it.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core.settings import param
import numpy as np

#: The most a shaped floor (``covariance.rotation_floor_shape``) stretches one direction's
#: variance.
MAX_FLOOR_STRETCH = 100.0

#: The Hessian standard deviations (m, rad; geometric means over a block) at which
#: ``covariance.hessian_size_exponent`` leaves the scale as it is: about a simulated HDL-64
#: scan's at ``odometry.covariance_scale`` 5 (docs/covariance.md).
REFERENCE_SIGMAS = (0.002, float(np.radians(0.005)))

#: The most ``covariance.hessian_size_exponent`` multiplies or divides a block's variance by.
MAX_SIZE_FACTOR = 1000.0

#: The fine alignment's residual variance ``2E / (n - 6)`` (:attr:`Alignment.residual_variance`,
#: a mean squared Mahalanobis residual per inlier) at which ``covariance.residual_*_exponent``
#: leaves the floors as they are: about a simulated HDL-64 scan's, tracked against its local
#: map (0.2-0.3; docs/covariance.md, session 20).
REFERENCE_RESIDUAL = 0.25


@dataclass
class CovarianceConfig:
    """Calibration of the fine alignment's pose covariance (docs/covariance.md)."""

    floor_translation: float = param(
        0.00523,
        'Standard deviation added to every axis of the pose covariance (errors the '
        'Hessian does not see: deskew, labels, the keyframe).',
        unit='m',
        low=0.0,
        high=100.0,
    )
    floor_rotation: float = param(
        0.0643,
        'Standard deviation added to every rotation axis of the pose covariance.',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    per_metre_translation: float = param(
        0.0018,
        'Standard deviation added to every translation axis per metre of the motion the '
        'covariance describes (from the keyframe to the scan).',
        unit='m/m',
        low=0.0,
        high=10.0,
    )
    per_metre_rotation: float = param(
        0.000251,
        'Standard deviation added to every rotation axis per metre of that motion.',
        unit='deg/m',
        low=0.0,
        high=100.0,
    )
    per_degree_translation: float = param(
        0.000239,
        'Standard deviation added to every translation axis per degree the motion turned '
        '(deskew and timing errors grow in turns).',
        unit='m/deg',
        low=0.0,
        high=10.0,
    )
    per_degree_rotation: float = param(
        0.00155,
        'Standard deviation added to every rotation axis per degree the motion turned.',
        unit='deg/deg',
        low=0.0,
        high=10.0,
    )
    per_correction_translation: float = param(
        1.47,
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
        0.434,
        'Standard deviation added to every rotation axis per degree that the accepted pose '
        'turned from the prediction (times the sweep share) beyond correction_free_rotation. '
        '0: off.',
        unit='deg/deg',
        low=0.0,
        high=10.0,
    )
    correction_free_translation: float = param(
        0.0752,
        'The part of the distance from the prediction (times the sweep share) that adds '
        'nothing (per_correction_translation).',
        unit='m',
        low=0.0,
        high=100.0,
    )
    correction_free_rotation: float = param(
        2.81,
        'The part of the turn from the prediction that adds nothing (per_correction_rotation).',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    correction_sweep: float = param(
        0.0775,
        "The sweep time over which the prediction's velocity error bends the scan: the "
        'correction counts times min(1, correction_sweep / horizon), the horizon being the '
        'time since the last accepted scan (a prediction 3 m off after 1 s bends a sweep as '
        'much as one 0.3 m off after 0.1 s). 0: the correction counts whole.',
        unit='s',
        low=0.0,
        high=10.0,
    )
    rotation_floor_shape: float = param(
        0.26,
        "The rotation floor follows the shape of the Hessian's rotation block: along each of "
        'its eigen-directions the floor variance is multiplied by (variance / geometric mean '
        'of the three) to this power, capped at 100 (the product stays 1). A roll the scene '
        'observes worse than the pitch (a straight road, the ground seen on one side) gets '
        'more of the floor. 0: isotropic (docs/covariance.md).',
        low=0.0,
        high=2.0,
    )
    translation_floor_shape: float = param(
        0.0,
        "The translation floor follows the shape of the Hessian's translation block, as "
        'rotation_floor_shape does the rotation: a direction the scene constrains worse '
        '(along a straight road) gets more of it. 0: isotropic (docs/covariance.md).',
        low=0.0,
        high=2.0,
    )
    hessian_size_exponent: float = param(
        0.549,
        'The scale follows the size of the Hessian covariance: each block (translation, '
        'rotation) is multiplied by (its geometric-mean variance / a reference) to minus this '
        'power, so a dense scan, whose many correlated residuals make the Hessian understate '
        'the error more, gets a larger scale than a sparse one. 0: one scale for every scan '
        '(docs/covariance.md).',
        low=0.0,
        high=1.0,
    )
    floor_size_exponent: float = param(
        0.374,
        "The floors follow the size of the Hessian covariance too: each block's floor "
        'variance (every term above, translation and rotation apart) is multiplied by (the '
        "block's geometric-mean variance / the reference of hessian_size_exponent) to this "
        'power: a sparse scan (VLP-16, solid state) drifts more than a dense one per metre. '
        '0: the same floors for every scan (docs/covariance.md).',
        low=0.0,
        high=2.0,
    )
    along_correction: float = param(
        0.161,
        'Standard deviation added along the direction from the prediction to the accepted '
        'pose, per metre of that correction (times the sweep share, correction_sweep): a '
        'scan deskewed by a prediction that was off stays off along it. 0: off '
        '(docs/covariance.md).',
        unit='m/m',
        low=0.0,
        high=10.0,
    )
    jerk_along: float = param(
        0.3,
        'Standard deviation added along the direction from the prediction to the accepted '
        'pose, per metre of that correction (times min(1, jerk_window / horizon)) beyond '
        'jerk_free: a hand that jerks between scans a few sweeps apart leaves the scan off '
        'along the correction by a third to a whole of it (the handheld walk at stride 3: '
        '10-25 cm off for 15-30 cm corrections). 0: off (docs/covariance.md).',
        unit='m/m',
        low=0.0,
        high=10.0,
    )
    jerk_free: float = param(
        0.13,
        'The part of the correction (times the jerk_window share) that adds nothing to '
        'jerk_along.',
        unit='m',
        low=0.0,
        high=100.0,
    )
    jerk_window: float = param(
        0.3,
        'The time over which jerk_along counts the whole correction: beyond it the '
        'correction counts times jerk_window / horizon (a prediction over a second is a '
        'guess the registration replaces, not a bend of the scan).',
        unit='s',
        low=0.0,
        high=10.0,
    )
    jerk_per_degree: float = param(
        0.03,
        'Standard deviation added to every translation axis per degree that the accepted '
        'pose turned from the prediction (times the jerk_window share) beyond '
        'jerk_free_turn: a turn the prediction missed bends the sweep, and the '
        'scan lands off by centimetres (the handheld walk at stride 3: up to 14 cm off after '
        '13 deg). 0: off (docs/covariance.md).',
        unit='m/deg',
        low=0.0,
        high=10.0,
    )
    jerk_free_turn: float = param(
        8.5,
        'The part of the turn from the prediction (times the jerk_window share) that adds '
        'nothing to jerk_per_degree (a car at stride 3 missing a turn by 4-8 deg stays '
        'within 6 cm).',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    jerk_max_turn: float = param(
        30.0,
        'jerk_along is off when the accepted pose turned more than this from the prediction '
        '(the registration replaced the prediction instead of refining it).',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    per_bend_translation: float = param(
        0.0,
        'Standard deviation added to every translation axis per metre that the sweep '
        "alignment's twist bent the scan (its points' largest move against the deskew's "
        'twist, where the scan was deskewed again with it), times min(1, bend_window / '
        'horizon), beyond bend_free: the sweep alignment corrects a wrong deskew only in '
        'part (HDL-64 field drives at stride 1: scans bent by 2-6 m were 6-23 cm and '
        '0.3-1 deg off). 0: off (docs/covariance.md).',
        unit='m/m',
        low=0.0,
        high=10.0,
    )
    per_bend_rotation: float = param(
        0.0,
        'Standard deviation added to every rotation axis per metre of that bend (times the '
        'bend_window share) beyond bend_free. 0: off.',
        unit='deg/m',
        low=0.0,
        high=100.0,
    )
    bend_free: float = param(
        0.0,
        'The part of the bend (times the bend_window share) that adds nothing to '
        'per_bend_translation and per_bend_rotation.',
        unit='m',
        low=0.0,
        high=100.0,
    )
    bend_window: float = param(
        0.0,
        'The time over which the bend counts whole: beyond it, times bend_window / horizon '
        '(a scan a second after the last one is bent by a twist the registration replaced '
        'whole). 0: the bend counts whole.',
        unit='s',
        low=0.0,
        high=10.0,
    )
    bend_relief: float = param(
        0.0,
        'The share of the correction terms (per_correction_*, along_correction, jerk_*) '
        'taken off a scan the sweep alignment deskewed again: they stand for a scan '
        'deskewed by a prediction that was off, and the sweep alignment replaced that '
        'deskew (0: kept whole, 1: none on a bent scan).',
        low=0.0,
        high=1.0,
    )
    residual_translation_exponent: float = param(
        1.0,
        "The translation floor follows the fine alignment's residual: its variance (every "
        'translation term above) is multiplied by (the residual variance 2E / (n - 6) / '
        '0.25) to this power, within residual_min_factor and residual_max_factor. A tracked '
        'scan that fits its map tighter than a typical one (HDL-64 at stride 1: 0.15-0.2) is '
        'closer than the floors say (they were under-confident there, NEES mean 2.7-3.0). '
        '0: off (docs/covariance.md).',
        low=0.0,
        high=4.0,
    )
    residual_rotation_exponent: float = param(
        0.0,
        'The rotation floor follows the residual likewise (residual_translation_exponent). '
        '0: off.',
        low=0.0,
        high=4.0,
    )
    residual_min_factor: float = param(
        0.5,
        'The least the residual (residual_*_exponent) multiplies a floor variance by: a scan '
        'that fits its map tighter than the reference is not that much closer '
        '(docs/covariance.md).',
        low=0.0,
        high=1.0,
    )
    residual_max_factor: float = param(
        1.0,
        'The most the residual multiplies a floor variance by: a handheld sweep fits its map '
        'up to 60 times looser than a car sweep without being that much further off (1: a '
        'loose fit keeps the floors, as does a value below 1; docs/covariance.md).',
        low=0.0,
        high=100.0,
    )
    keyframe_share: float = param(
        0.3,
        "The share of the keyframe's own frame covariance added to a scan's when the scan "
        'fits its map tightly and the keyframe fitted it loosely (keyframe_residual_ratio, '
        'keyframe_scan_residual): the pose is scored and published relative to the keyframe, '
        'and a keyframe misplaced against the map carries its error into the scan that fits '
        'the map (HDL-64 field drive seed 0 at stride 10: scans 10-24 cm off after keyframes '
        "that fitted 4-7 times looser). Rotated into the scan's axes. 0: off "
        '(docs/covariance.md).',
        low=0.0,
        high=10.0,
    )
    keyframe_residual_ratio: float = param(
        3.0,
        "keyframe_share applies when the keyframe's residual variance 2E / (n - 6) exceeds "
        "this many times the scan's own (both known).",
        low=0.0,
        high=1000.0,
    )
    keyframe_scan_residual: float = param(
        0.75,
        'keyframe_share applies only to a scan whose own residual variance is below this (a '
        "scan that fits its map tightly: its error is the keyframe's; a handheld sweep fits "
        "at 1.5-16 and its keyframe's looseness says little). 0: no bound.",
        low=0.0,
        high=1000.0,
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
    """Return the inflation ``D`` (..., 6, 6) of ``covariance`` (..., 6, 6, ROS order)."""
    covariance = np.asarray(covariance, dtype=np.float64)
    flat = covariance.reshape(-1, 6, 6)
    eigen = (BlockEigen.of(flat[:, :3, :3]), BlockEigen.of(flat[:, 3:, 3:]))
    return _degenerate_inflation(eigen, cfg).reshape(covariance.shape)


def _degenerate_inflation(
    eigen: tuple[BlockEigen, BlockEigen], cfg: CovarianceConfig
) -> np.ndarray:
    """:func:`degenerate_inflation` from the blocks' eigen-decompositions (K samples)."""
    inflation = np.zeros((len(eigen[0].values), 6, 6))
    if cfg.degenerate_ratio <= 0:
        return inflation
    sigmas = (cfg.degenerate_translation, np.radians(cfg.degenerate_rotation))
    for block, sigma, decomposed in zip((slice(0, 3), slice(3, 6)), sigmas, eigen, strict=True):
        if sigma <= 0:
            continue
        values = decomposed.values
        weak = values > cfg.degenerate_ratio * np.maximum(values[:, :1], 1e-300)
        inflation[:, block, block] = sigma**2 * np.einsum(
            'kij,kj,klj->kil', decomposed.vectors, weak.astype(np.float64), decomposed.vectors
        )
    return inflation


def calibrated_covariance(
    hessian_covariance: np.ndarray,
    scale: float,
    cfg: CovarianceConfig,
    distance: float = 0.0,
    turn_deg: float = 0.0,
    correction: tuple[float, float] = (0.0, 0.0),
    horizon_s: float = 0.0,
    correction_direction: np.ndarray | None = None,
    bend_m: float = 0.0,
    residual_variance: float = 0.0,
) -> np.ndarray:
    """
    Return ``s * C_H + D + floor(d)`` (module docstring) of a covariance (6, 6), ROS order.

    ``hessian_covariance``: ``inv(H) * 2E / (n - 6)`` (``scale`` 1) in either axes: the
    floors follow the Hessian's eigen-directions or are isotropic, so the result rotates
    with the input. ``correction``: the distance (m) and angle (deg) between the accepted
    pose and the motion model's prediction (the ``per_correction_*`` terms); ``horizon_s``:
    the time the prediction spanned, from the last accepted scan (0: unknown, the
    correction counts whole); ``correction_direction``: the translation (3,) from the
    prediction to the accepted pose in the covariance's axes (``along_correction``; None:
    that term is off); ``bend_m``: how far the sweep alignment's twist bent the scan it
    deskewed again (``per_bend_*``, ``bend_relief``; 0: not); ``residual_variance``: the
    fine alignment's ``2E / (n - 6)`` (``residual_*_exponent``; 0: unknown, the floors as
    they are). One sample of :func:`calibrated_covariances`.
    """
    inputs = CovarianceInputs.single(
        distance, turn_deg, correction, horizon_s, correction_direction, bend_m, residual_variance
    )
    hessian = np.asarray(hessian_covariance, dtype=np.float64)[None]
    return calibrated_covariances(hessian, scale, cfg, inputs)[0]


@dataclass
class CovarianceInputs:
    """What the calibration reads besides the Hessian, for K samples (docs/covariance.md)."""

    distances: np.ndarray  # (K,) m, the motion the covariance describes
    turns_deg: np.ndarray  # (K,) deg, its rotation angle
    corrections: np.ndarray  # (K, 2) m and deg of the accepted pose from the prediction
    horizons_s: np.ndarray  # (K,) s, the prediction's horizon (0: unknown)
    directions: np.ndarray  # (K, 3) translation from the prediction (zeros: none)
    bends_m: np.ndarray | None = None  # (K,) m, the sweep alignment's bend (None: zeros)
    residuals: np.ndarray | None = None  # (K,) the alignment's 2E / (n - 6) (None, 0: unknown)

    @classmethod
    def single(
        cls,
        distance: float,
        turn_deg: float,
        correction: tuple[float, float],
        horizon_s: float,
        direction: np.ndarray | None,
        bend_m: float = 0.0,
        residual_variance: float = 0.0,
    ) -> CovarianceInputs:
        """Return the inputs of one sample."""
        return cls(
            np.array([distance], dtype=np.float64),
            np.array([turn_deg], dtype=np.float64),
            np.array([correction], dtype=np.float64).reshape(1, 2),
            np.array([horizon_s], dtype=np.float64),
            np.zeros((1, 3)) if direction is None else np.asarray(direction, np.float64)[None, :3],
            np.array([bend_m], dtype=np.float64),
            np.array([residual_variance], dtype=np.float64),
        )

    def bends(self) -> np.ndarray:
        """Return the sweep alignment's bend of each sample (K,) in m, zeros where not given."""
        if self.bends_m is None:
            return np.zeros(len(self.distances))
        return np.asarray(self.bends_m, dtype=np.float64)

    def residual_factors(self, cfg: CovarianceConfig) -> np.ndarray:
        """
        Return the floors' variance factors (K, 2) of the residual, translation and rotation.

        ``(r / REFERENCE_RESIDUAL) ** residual_*_exponent`` within ``residual_min_factor``
        and ``residual_max_factor``; 1 where the residual ``r`` is unknown (0).
        """
        exponents = (cfg.residual_translation_exponent, cfg.residual_rotation_exponent)
        count = len(self.distances)
        if self.residuals is None or not np.any(exponents):
            return np.ones((count, len(exponents)))
        residuals = np.asarray(self.residuals, dtype=np.float64)
        known = np.isfinite(residuals) & (residuals > 0.0)
        logs = np.log(np.where(known, residuals, REFERENCE_RESIDUAL) / REFERENCE_RESIDUAL)
        factors = np.exp(logs[:, None] * np.asarray(exponents, dtype=np.float64)[None, :])
        low, high = min(cfg.residual_min_factor, 1.0), max(cfg.residual_max_factor, 1.0)
        return np.clip(factors, low, high)


@dataclass
class BlockEigen:
    """Eigen-decompositions of K covariance blocks (3, 3); ``usable``: finite and not zero."""

    values: np.ndarray  # (K, 3) ascending
    vectors: np.ndarray  # (K, 3, 3) columns
    usable: np.ndarray  # (K,) bool

    @classmethod
    def of(cls, blocks: np.ndarray) -> BlockEigen:
        """Decompose ``blocks`` (K, 3, 3); a block that is zero or not finite: the identity."""
        blocks = np.asarray(blocks, dtype=np.float64).reshape(-1, 3, 3)
        usable = np.all(np.isfinite(blocks), axis=(1, 2)) & np.any(blocks != 0.0, axis=(1, 2))
        safe = np.where(usable[:, None, None], blocks, np.eye(3))
        values, vectors = np.linalg.eigh(safe)  # its lower triangle
        return cls(values, vectors, usable)

    def log_volume(self) -> np.ndarray:
        """Return the log of the eigenvalues' geometric mean (K,); 0 where not positive."""
        positive = self.usable & np.all(self.values > 0.0, axis=1)
        logs = np.log(np.where(positive[:, None], self.values, 1.0))
        return logs.mean(axis=1)


def hessian_eigen(hessian_covariances: np.ndarray) -> tuple[BlockEigen, BlockEigen]:
    """Return the translation and rotation blocks' :class:`BlockEigen` of (K, 6, 6)."""
    covariances = np.asarray(hessian_covariances, dtype=np.float64)
    return BlockEigen.of(covariances[:, :3, :3]), BlockEigen.of(covariances[:, 3:, 3:])


def calibrated_covariances(
    hessian_covariances: np.ndarray,
    scale: float,
    cfg: CovarianceConfig,
    inputs: CovarianceInputs,
    eigen: tuple[BlockEigen, BlockEigen] | None = None,
) -> np.ndarray:
    """
    Return the calibrated covariances (K, 6, 6) of K Hessian covariances (K, 6, 6).

    ``eigen``: :func:`hessian_eigen` of the Hessian covariances, when known (a fit scores
    many calibrations on the same samples; the floors' shapes, the degenerate directions
    and the size do not change with the scale).
    """
    hessian_covariances = np.asarray(hessian_covariances, np.float64)
    eigen = hessian_eigen(hessian_covariances) if eigen is None else eigen
    log_ratios = size_log_ratios(eigen, scale)
    scaled = follow_hessian_size(hessian_covariances * scale, log_ratios, cfg)
    share = sweep_shares(inputs.horizons_s, cfg)
    moved_m, turned_deg = inputs.corrections[:, 0] * share, inputs.corrections[:, 1] * share
    relief = correction_relief(inputs, cfg)
    bend = np.maximum(
        inputs.bends() * sweep_shares(inputs.horizons_s, cfg, cfg.bend_window) - cfg.bend_free,
        0.0,
    )
    sigma_t = (
        cfg.floor_translation
        + cfg.per_metre_translation * inputs.distances
        + cfg.per_degree_translation * inputs.turns_deg
        + relief
        * cfg.per_correction_translation
        * np.maximum(moved_m - cfg.correction_free_translation, 0.0)
        + cfg.per_bend_translation * bend
    )
    sigma_r = np.radians(
        cfg.floor_rotation
        + cfg.per_metre_rotation * inputs.distances
        + cfg.per_degree_rotation * inputs.turns_deg
        + relief
        * cfg.per_correction_rotation
        * np.maximum(turned_deg - cfg.correction_free_rotation, 0.0)
        + cfg.per_bend_rotation * bend
    )
    if cfg.floor_size_exponent != 0.0:  # a sparse scan's errors no Hessian sees are larger
        factors = size_factors(log_ratios, 0.5 * cfg.floor_size_exponent)
        sigma_t, sigma_r = sigma_t * factors[:, 0], sigma_r * factors[:, 1]
    floor = np.zeros(scaled.shape)
    floor[:, :3, :3] = (sigma_t**2)[:, None, None] * _shape(eigen[0], cfg.translation_floor_shape)
    floor[:, 3:, 3:] = (sigma_r**2)[:, None, None] * _shape(eigen[1], cfg.rotation_floor_shape)
    correction_variance = along_correction(inputs.directions, share, cfg) + jerk_along(inputs, cfg)
    floor[:, :3, :3] += (relief**2)[:, None, None] * correction_variance
    residual = inputs.residual_factors(cfg)  # a tight fit's floors shrink
    floor[:, :3, :3] *= residual[:, 0, None, None]
    floor[:, 3:, 3:] *= residual[:, 1, None, None]
    covariance = scaled + _degenerate_inflation(eigen, cfg) + floor
    return 0.5 * (covariance + np.swapaxes(covariance, -1, -2))


def correction_relief(inputs: CovarianceInputs, cfg: CovarianceConfig) -> np.ndarray:
    """
    Return the factor (K,) of the correction terms' standard deviations.

    ``1 - bend_relief`` on a scan the sweep alignment deskewed again (its bend above 0), 1
    elsewhere.
    """
    relief = np.ones(len(inputs.distances))
    relief[inputs.bends() > 0.0] = 1.0 - cfg.bend_relief
    return relief


def size_log_ratios(eigen: tuple[BlockEigen, BlockEigen], scale: float) -> np.ndarray:
    """
    Return ``log(g / g_ref)`` (K, 2) of the translation and the rotation block.

    ``g``: the geometric mean of the eigenvalues of the block of ``scale`` times the
    Hessian covariance of ``eigen``, ``g_ref`` the square of :data:`REFERENCE_SIGMAS`; 0 for
    a block that is zero, singular or not finite.
    """
    ratios = np.zeros((len(eigen[0].values), 2))
    for index, (reference, decomposed) in enumerate(zip(REFERENCE_SIGMAS, eigen, strict=True)):
        ratio = decomposed.log_volume() + np.log(scale) - 2.0 * np.log(reference)
        ratios[:, index] = np.where(decomposed.usable, ratio, 0.0)
    return ratios


def size_factors(log_ratios: np.ndarray, exponent: float) -> np.ndarray:
    """Return ``(g / g_ref) ** exponent`` (K, 2), within 1 / and :data:`MAX_SIZE_FACTOR`."""
    return np.clip(np.exp(exponent * log_ratios), 1 / MAX_SIZE_FACTOR, MAX_SIZE_FACTOR)


def follow_hessian_size(
    scaled: np.ndarray, log_ratios: np.ndarray, cfg: CovarianceConfig
) -> np.ndarray:
    """
    ``scaled`` (K, 6, 6) times ``(g / g_ref) ** -hessian_size_exponent`` per block.

    ``log_ratios``: :func:`size_log_ratios` of ``scaled``. Fewer or worse spread points
    give a larger Hessian covariance, and their residuals are less correlated than a dense
    scan's: with the exponent, a block's scale grows as the Hessian tightens.
    """
    if cfg.hessian_size_exponent == 0.0:
        return scaled
    root = np.sqrt(np.repeat(size_factors(log_ratios, -cfg.hessian_size_exponent), 3, axis=1))
    return scaled * root[:, :, None] * root[:, None, :]


def along_correction(
    directions: np.ndarray, share: np.ndarray, cfg: CovarianceConfig
) -> np.ndarray:
    """
    Return the translation variance (K, 3, 3) along each correction's direction.

    ``(along_correction * k * |c|)^2 u u^T``, ``c`` the translation from the prediction to
    the accepted pose, ``u = c / |c|`` and ``k`` the sweep share (:func:`sweep_shares`): a
    scan deskewed by a prediction that was off stays off in the same direction (the field
    drives' and the solid-state sensor's largest errors point along their correction).
    """
    if cfg.along_correction <= 0.0:
        return np.zeros((len(directions), 3, 3))
    return (cfg.along_correction * share[:, None, None]) ** 2 * np.einsum(
        'ki,kj->kij', directions, directions
    )


def jerk_along(inputs: CovarianceInputs, cfg: CovarianceConfig) -> np.ndarray:
    """
    Return the translation variance (K, 3, 3) of a jerk of the motion between the scans.

    ``(jerk_along * max(k |c| - jerk_free, 0))^2 u u^T`` with ``c`` the translation from
    the prediction to the accepted pose, ``u = c / |c|``, ``k = min(1, jerk_window /
    horizon)``, plus ``(jerk_per_degree * max(k a - jerk_free_turn, 0))^2 I3``
    with ``a`` the angle (deg) between the prediction and the accepted pose; 0 where that
    angle exceeds ``jerk_max_turn`` (the registration replaced the prediction). A hand's
    motion a few sweeps apart changes faster than the constant-velocity prediction
    follows, and the accepted scan stays off along the correction (docs/covariance.md).
    """
    directions = inputs.directions
    if cfg.jerk_along <= 0.0 and cfg.jerk_per_degree <= 0.0:
        return np.zeros((len(directions), 3, 3))
    lengths = np.linalg.norm(directions, axis=1)
    share = sweep_shares(inputs.horizons_s, cfg, cfg.jerk_window)
    sigma = cfg.jerk_along * np.maximum(share * lengths - cfg.jerk_free, 0.0)
    turned = inputs.corrections[:, 1]
    beyond_deg = np.maximum(share * turned - cfg.jerk_free_turn, 0.0)
    sigma_turn = cfg.jerk_per_degree * beyond_deg
    replaced = turned > cfg.jerk_max_turn
    sigma[replaced], sigma_turn[replaced] = 0.0, 0.0
    unit = directions / np.maximum(lengths, 1e-12)[:, None]
    variance = (sigma**2)[:, None, None] * np.einsum('ki,kj->kij', unit, unit)
    return variance + (sigma_turn**2)[:, None, None] * np.eye(3)


def floor_shape(blocks: np.ndarray, exponent: float) -> np.ndarray:
    """
    Return the shape (..., 3, 3) of a floor that follows covariance ``blocks`` (..., 3, 3).

    ``U diag(w) U^T`` with ``U`` the blocks' eigen-directions and ``w = (lambda / g) ** exponent``,
    ``g`` the geometric mean of the eigenvalues ``lambda`` (so ``prod(w) = 1``: the floor's
    volume is kept, only its shape follows the Hessian), ``w`` at most
    ``MAX_FLOOR_STRETCH``. Exponent 0, or a block that is zero or not finite: the identity.
    """
    blocks = np.asarray(blocks, dtype=np.float64)
    return _shape(BlockEigen.of(blocks), exponent).reshape(blocks.shape)


def _shape(eigen: BlockEigen, exponent: float) -> np.ndarray:
    """:func:`floor_shape` from the blocks' eigen-decompositions (K, 3, 3)."""
    identity = np.broadcast_to(np.eye(3), eigen.vectors.shape)
    if exponent <= 0.0:
        return identity.copy()
    logs = np.log(np.maximum(eigen.values, 1e-30))
    weights = np.exp(exponent * (logs - logs.mean(axis=-1, keepdims=True)))
    weights = np.minimum(weights, MAX_FLOOR_STRETCH)
    shaped = np.einsum('kij,kj,klj->kil', eigen.vectors, weights, eigen.vectors)
    return np.where(eigen.usable[:, None, None], shaped, identity)


def sweep_share(horizon_s: float, cfg: CovarianceConfig) -> float:
    """Return ``min(1, correction_sweep / horizon)``: the share of a correction in the sweep."""
    return float(sweep_shares(np.array([horizon_s], dtype=np.float64), cfg)[0])


def sweep_shares(
    horizons_s: np.ndarray, cfg: CovarianceConfig, sweep_s: float | None = None
) -> np.ndarray:
    """
    :func:`sweep_share` of K horizons (K,): 1 where the horizon is unknown (0).

    ``sweep_s``: the time that counts whole (None: ``correction_sweep``).
    """
    sweep_s = cfg.correction_sweep if sweep_s is None else sweep_s
    share = np.ones(horizons_s.shape)
    if sweep_s > 0.0:
        timed = horizons_s > 0.0
        share[timed] = np.minimum(1.0, sweep_s / horizons_s[timed])
    return share


def motion_size(motion: np.ndarray) -> tuple[float, float]:
    """Return the distance (m) and the rotation angle (deg) of a motion (4, 4)."""
    cosine = np.clip((np.trace(motion[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.linalg.norm(motion[:3, 3])), float(np.degrees(np.arccos(cosine)))


def keyframe_shares(
    residuals: np.ndarray, keyframe_residuals: np.ndarray, cfg: CovarianceConfig
) -> np.ndarray:
    """
    Return the share (K,) of the keyframe's covariance each scan's covariance gets.

    ``covariance.keyframe_share`` where the keyframe's residual variance exceeds
    ``covariance.keyframe_residual_ratio`` times the scan's (both known, above 0) and the
    scan's is below ``covariance.keyframe_scan_residual`` (0: any), else 0.
    """
    residuals = np.asarray(residuals, dtype=np.float64)
    keyframe_residuals = np.asarray(keyframe_residuals, dtype=np.float64)
    if cfg.keyframe_share <= 0.0:
        return np.zeros(residuals.shape)
    known = (residuals > 0.0) & (keyframe_residuals > 0.0)
    known &= np.isfinite(residuals) & np.isfinite(keyframe_residuals)
    loose = known & (keyframe_residuals > cfg.keyframe_residual_ratio * residuals)
    if cfg.keyframe_scan_residual > 0.0:
        loose &= residuals < cfg.keyframe_scan_residual
    return np.where(loose, cfg.keyframe_share, 0.0)


def keyframe_covariances(
    keyframe_covariances: np.ndarray, T_keyframe_scans: np.ndarray, shares: np.ndarray
) -> np.ndarray:
    """
    Return the keyframe's covariances (K, 6, 6) in the scans' axes, times ``shares`` (K,).

    The pose relative to the keyframe, ``T_keyframe_scan = inv(T_keyframe) T_scan``, with
    both poses perturbed on the right by ``[t, rotvec]`` errors, is off by the scan's
    error minus ``Ad(inv(T_keyframe_scan))`` times the keyframe's: its covariance adds
    ``Ad C_k Ad^T``, ``Ad = [[R, [t]x R], [0, R]]`` of ``inv(T_keyframe_scan)``
    (``keyframe_covariances``: (K, 6, 6) in the keyframe's axes, ROS order).
    """
    T = np.asarray(T_keyframe_scans, dtype=np.float64).reshape(-1, 4, 4)
    covariances = np.asarray(keyframe_covariances, dtype=np.float64).reshape(-1, 6, 6)
    rotation = np.swapaxes(T[:, :3, :3], -1, -2)  # of inv(T): R^T, -R^T t
    translation = -np.einsum('kij,kj->ki', rotation, T[:, :3, 3])
    skew = np.zeros((len(T), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = (
        -translation[:, 2],
        translation[:, 1],
        -translation[:, 0],
    )
    skew -= np.swapaxes(skew, -1, -2)
    adjoint = np.zeros((len(T), 6, 6))
    adjoint[:, :3, :3], adjoint[:, 3:, 3:] = rotation, rotation
    adjoint[:, :3, 3:] = skew @ rotation
    moved = adjoint @ covariances @ np.swapaxes(adjoint, -1, -2)
    shares = np.asarray(shares, dtype=np.float64).reshape(-1)
    finite = np.all(np.isfinite(moved), axis=(1, 2))
    return np.where(finite[:, None, None], moved * shares[:, None, None], 0.0)


def keyframe_term(
    keyframe_covariance: np.ndarray | None,
    T_keyframe_scan: np.ndarray,
    residual_variance: float,
    keyframe_residual: float,
    cfg: CovarianceConfig,
) -> np.ndarray:
    """
    Return what the keyframe adds to a scan's covariance (6, 6; zeros: nothing).

    ``keyframe_covariance``: the keyframe's own frame covariance when it was accepted
    (its axes; None: unknown, as for the first scan); ``residual_variance`` and
    ``keyframe_residual``: the scan's and the keyframe's ``2E / (n - 6)``
    (:func:`keyframe_shares`, :func:`keyframe_covariances`).
    """
    if keyframe_covariance is None or cfg.keyframe_share <= 0.0:
        return np.zeros((6, 6))
    share = keyframe_shares(np.array([residual_variance]), np.array([keyframe_residual]), cfg)
    if share[0] <= 0.0:
        return np.zeros((6, 6))
    return keyframe_covariances(keyframe_covariance[None], T_keyframe_scan[None], share)[0]

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
NEES of the pose covariance on real pairs and drives, and its calibration (docs/covariance.md).

A sample is one accepted estimate: its error ``e = log(T_truth^-1 T_estimate)``
(``[t, rotvec]``, the estimate's axes) and its Hessian covariance ``C_H`` (scale 1, no
calibration). The NEES of a calibration is ``e^T inv(C) e`` with ``C`` from
:func:`~mlsemreg_ros.core.alignment.covariance.calibrated_covariances`; a consistent
covariance gives chi-square values with 6 degrees of freedom: mean 6, 95 % below 12.59.
The samples are kept, so a calibration is scored without registering again.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import itertools
from typing import Any

from mlsemreg_ros.core.alignment.covariance import (
    BlockEigen,
    calibrated_covariances,
    CovarianceConfig,
    CovarianceInputs,
    hessian_eigen,
    keyframe_covariances,
    keyframe_shares,
    motion_size,
    no_calibration,
)
import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

#: The 95 % bound of a chi-square with 6 degrees of freedom.
NEES_BOUND_95 = float(chi2.ppf(0.95, 6))

#: The target per data set: a NEES mean within these bounds (6 is ideal) ...
TARGET_MEAN = (3.0, 9.0)
#: ... and at least this share (percent) of the values inside the 95 % bound.
TARGET_INSIDE_PCT = 90.0


def meets_target(summary: dict[str, float]) -> bool:
    """Whether a data set's :func:`nees_summary` meets the target (docs/covariance.md)."""
    mean, inside = summary['nees_mean'], summary['inside_95_pct']
    low, high = TARGET_MEAN
    return bool(low <= mean <= high and inside >= TARGET_INSIDE_PCT)


@dataclass
class CovarianceSample:
    """One accepted estimate: its error (6,) and its Hessian covariance (6, 6), ROS order."""

    error: np.ndarray
    hessian_covariance: np.ndarray
    distance: float = 0.0  # m, the motion the covariance describes (keyframe to scan)
    turn_deg: float = 0.0  # deg, the rotation angle of that motion
    correction_m: float = 0.0  # m, the accepted pose from the motion model's prediction
    correction_deg: float = 0.0  # deg, the rotation between them
    gap_s: float = 0.0  # s, from the last accepted scan (the prediction's horizon); 0: none
    #: (6,) ``[t, rotvec]`` of ``inv(T_predicted) T_estimate``, the scan's axes (zeros: none)
    correction_vector: np.ndarray = field(default_factory=lambda: np.zeros(6))
    scan_points: int = 0  # points of the scan as the odometry kept them (0: unknown)
    inliers: int = 0  # inliers of the accepted fine alignment (0: unknown)
    bend_m: float = 0.0  # m, the sweep alignment's bend of the scan (0: not deskewed again)
    sweep_change_m: float = 0.0  # m, the sweep alignment's estimated bend, kept or not
    source: int = 0  # the step's source: SOURCES' index (0: unknown)
    residual_variance: float = 0.0  # the accepted fine alignment's 2E / (n - 6) (0: unknown)
    inlier_fraction: float = 0.0  # the accepted fine alignment's inlier share (0: unknown)
    #: how many samples back the keyframe's own sample is (0: the keyframe is no sample)
    keyframe_back: int = 0
    #: (6,) ``[t, rotvec]`` of the estimate ``T_keyframe_scan`` (zeros: unknown)
    relative: np.ndarray = field(default_factory=lambda: np.zeros(6))


#: The step sources a sample records (:attr:`CovarianceSample.source`).
SOURCES = ('', 'prediction', 'global', 'prediction+global', 'first')


def source_code(source: str) -> int:
    """Return the index of a step's source in :data:`SOURCES` (0: another or none)."""
    return SOURCES.index(source) if source in SOURCES else 0


def pose_error(T_estimate: np.ndarray, T_truth: np.ndarray) -> np.ndarray:
    """``[t, rotvec]`` of ``T_truth^-1 T_estimate`` (as core.metrics' NEES)."""
    error = np.linalg.solve(np.asarray(T_truth, np.float64), np.asarray(T_estimate, np.float64))
    return np.concatenate([error[:3, 3], Rotation.from_matrix(error[:3, :3]).as_rotvec()])


def uncalibrated(config: Any) -> Any:
    """``config`` with covariance scale 1 and no calibration (the samples' covariance)."""
    return replace(config, covariance=no_calibration()).replace({'odometry.covariance_scale': 1.0})


def pair_samples(pair_files: list[Any], config: Any) -> list[CovarianceSample]:
    """Global registrations of pair files (accepted ones with a fine alignment)."""
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.datasets.pairs import load_pair

    registration = Registration(uncalibrated(config))
    samples = []
    for file in pair_files:
        pair = load_pair(file)
        source, target = registration.prepare_scans(
            {'points': pair.pts_src, 'labels': pair.label_src, 'voxelize': False},
            {'points': pair.pts_dst, 'labels': pair.label_dst, 'voxelize': False},
        )
        result = registration.register(source, target)
        if not result.success or result.alignment is None:
            continue
        covariance = result.alignment.covariance(1.0, axes='source')
        error = pose_error(result.transform, pair.trans_gt)
        alignment = result.alignment
        samples.append(
            CovarianceSample(
                error,
                covariance,
                *motion_size(result.transform),
                inliers=alignment.num_inliers,
                residual_variance=alignment.residual_variance,
                inlier_fraction=alignment.inlier_fraction,
            )
        )
    return samples


def stream_samples(scans: Any, config: Any) -> list[CovarianceSample]:
    """
    Run the odometry over ``scans``; return the samples as ``mlsemreg eval-bag`` scores them.

    ``scans``: objects with ``xyz``, ``labels``, ``stamp_ns``, ``point_times``, ``pose``
    and ``index``. A sample is the estimate relative to its keyframe against the ground
    truth, with its frame covariance.
    """
    from mlsemreg_ros.core.odometry import Odometry
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.core.rigid import relative_transform
    from mlsemreg_ros.evaluation.estimators import OdometryEstimator

    estimator = OdometryEstimator(Odometry(Registration(uncalibrated(config))))
    truth: dict[int, np.ndarray] = {}
    samples, last_accepted_ns = [], None
    sample_of: dict[int, int] = {}  # a scan's sample position, by its index
    for scan in scans:
        if scan.pose is not None:
            truth[scan.index] = np.asarray(scan.pose)
        estimate = estimator.step(scan)
        keyframe, previous_ns = estimate.keyframe_index, last_accepted_ns
        if estimate.accepted:
            last_accepted_ns = scan.stamp_ns
        if (
            not estimate.accepted
            or estimate.relative is None
            or estimate.frame_covariance is None
            or keyframe not in truth
            or scan.index not in truth
        ):
            continue
        T_truth = relative_transform(truth[keyframe], truth[scan.index])
        error = pose_error(estimate.relative, T_truth)
        size = motion_size(estimate.relative)
        step = estimator.last_step
        correction = prediction_correction(step)
        gap_s = 0.0 if previous_ns is None else (scan.stamp_ns - previous_ns) * 1e-9
        samples.append(
            CovarianceSample(
                error,
                estimate.frame_covariance,
                *size,
                *correction,
                gap_s,
                correction_vector(step),
                0 if step.points is None else len(step.points),
                accepted_inliers(step),
                float(getattr(step, 'sweep_bend_m', 0.0)),
                float(getattr(step, 'sweep_change_m', 0.0)),
                source_code(getattr(step, 'source', '')),
                float(getattr(step, 'residual_variance', 0.0)),
                float(getattr(step, 'inlier_fraction', 0.0)),
                len(samples) - sample_of[keyframe] if keyframe in sample_of else 0,
                transform_log(estimate.relative),
            )
        )
        sample_of[scan.index] = len(samples) - 1
    return samples


def transform_log(T: np.ndarray) -> np.ndarray:
    """``[t, rotvec]`` (6,) of a transform (4, 4)."""
    T = np.asarray(T, dtype=np.float64)
    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_rotvec()])


def _predicted_pose(step: Any) -> np.ndarray | None:
    """Return the motion model's prediction ``T_odom_current`` of a step (None: none)."""
    predicted = [
        c.T_initial
        for c in getattr(step, 'candidates', [])
        if c.name == 'prediction' and not getattr(c, 'still', False)
    ]
    return predicted[0] if predicted else None


def correction_vector(step: Any) -> np.ndarray:
    """``[t, rotvec]`` of an accepted step's pose from its prediction (zeros: none)."""
    predicted = _predicted_pose(step)
    if predicted is None or step.pose is None:
        return np.zeros(6)
    return pose_error(step.pose, predicted)


def accepted_inliers(step: Any) -> int:
    """Inliers of the acceptable candidate's alignment nearest the step's pose (0: none)."""
    usable = [c for c in getattr(step, 'candidates', []) if c.acceptable]
    if not usable or step.pose is None:
        return 0
    nearest = min(
        usable,
        key=lambda c: np.linalg.norm(c.alignment.T_target_source[:3, 3] - step.pose[:3, 3]),
    )
    return int(nearest.alignment.num_inliers)


def prediction_correction(step: Any) -> tuple[float, float]:
    """Distance (m) and angle (deg) of an accepted step's pose from its prediction (or 0, 0)."""
    from mlsemreg_ros.core.rigid import invert_transform

    predicted = _predicted_pose(step)
    if predicted is None or step.pose is None:
        return 0.0, 0.0
    return motion_size(invert_transform(predicted) @ step.pose)


def nees_values(
    samples: list[CovarianceSample], scale: float, cfg: CovarianceConfig
) -> np.ndarray:
    """Return the NEES of every sample under a calibration (NaN: a singular covariance)."""
    if not samples:
        return np.zeros(0)
    errors, covariances, inputs, eigen, links = _stack(samples)
    calibrated = calibrated_covariances(covariances, scale, cfg, inputs, eigen)
    calibrated = links.added_to(calibrated, cfg)
    values = np.full(len(samples), np.nan)
    usable = np.all(np.isfinite(calibrated), axis=(1, 2))
    usable[usable] = np.linalg.matrix_rank(calibrated[usable]) == 6
    if np.any(usable):
        solved = np.linalg.solve(calibrated[usable], errors[usable][:, :, None])[:, :, 0]
        values[usable] = np.einsum('ki,ki->k', errors[usable], solved)
    return values


@dataclass
class KeyframeLinks:
    """Each sample's keyframe among the samples, for ``covariance.keyframe_share``."""

    back: np.ndarray  # (K,) how many samples back the keyframe's sample is (0: none)
    T_keyframe_scans: np.ndarray  # (K, 4, 4) the estimates relative to the keyframe
    residuals: np.ndarray  # (K,) the samples' residual variances (0: unknown)

    @classmethod
    def of(cls, samples: list[CovarianceSample]) -> KeyframeLinks:
        """Return the links of a data set's samples (in their order)."""
        count = len(samples)
        back = np.array([s.keyframe_back for s in samples], dtype=int).reshape(count)
        back[(back < 0) | (back > np.arange(count))] = 0
        T = np.repeat(np.eye(4)[None], count, axis=0)
        for index, sample in enumerate(samples):
            T[index, :3, :3] = Rotation.from_rotvec(sample.relative[3:]).as_matrix()
            T[index, :3, 3] = sample.relative[:3]
        residuals = np.array([s.residual_variance for s in samples], dtype=np.float64)
        return cls(back, T, residuals.reshape(count))

    def added_to(self, calibrated: np.ndarray, cfg: CovarianceConfig) -> np.ndarray:
        """``calibrated`` (K, 6, 6) plus each keyframe's share, as the odometry adds it."""
        linked = self.back > 0
        if cfg.keyframe_share <= 0.0 or not np.any(linked):
            return calibrated
        keyframes = np.where(linked, np.arange(len(self.back)) - self.back, 0)
        kept = np.where(linked, self.residuals[keyframes], 0.0)
        shares = keyframe_shares(self.residuals, kept, cfg)
        return calibrated + keyframe_covariances(
            calibrated[keyframes], self.T_keyframe_scans, shares
        )


def _batch_nees(
    errors: np.ndarray,
    covariances: np.ndarray,
    inputs: CovarianceInputs,
    eigen: tuple[BlockEigen, BlockEigen],
    links: KeyframeLinks,
    scale: float,
    cfg: CovarianceConfig,
) -> np.ndarray:
    """:func:`nees_values` of stacked samples (:func:`_stack`), for the fits."""
    calibrated = links.added_to(
        calibrated_covariances(covariances, scale, cfg, inputs, eigen), cfg
    )
    solved = np.linalg.solve(calibrated, errors[:, :, None])[:, :, 0]
    return np.einsum('ki,ki->k', errors, solved)


def nees_summary(values: np.ndarray) -> dict[str, float]:
    """Mean, median and the share inside the 95 % bound (percent) of NEES values."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return {'samples': 0, 'nees_mean': np.nan, 'nees_median': np.nan, 'inside_95_pct': np.nan}
    return {
        'samples': int(finite.size),
        'nees_mean': float(finite.mean()),
        'nees_median': float(np.median(finite)),
        'inside_95_pct': float(100.0 * np.mean(finite <= NEES_BOUND_95)),
    }


def calibration_cost(summaries: list[dict[str, float]]) -> float:
    """
    How far a calibration is from consistent on the data sets (0 is ideal).

    Each data set that misses the target (:func:`meets_target`) counts 1; then the mean
    over the data sets of ``|log(mean / 6)|`` breaks the ties (below 1 unless a mean is 16
    times off).
    """
    misses, spread = 0, 0.0
    for s in summaries:
        mean = s['nees_mean']
        if not np.isfinite(mean) or mean <= 0:
            return np.inf
        misses += not meets_target(s)
        spread += abs(np.log(mean / 6.0)) / len(summaries)
    return misses + min(spread, 0.999)


def fit_calibration(
    datasets: dict[str, list[CovarianceSample]],
    grid: dict[str, tuple[float, ...]] | None = None,
) -> tuple[float, CovarianceConfig, float]:
    """
    Grid search: ``(scale, CovarianceConfig, cost)`` of the best calibration.

    ``grid``: the values tried per parameter (``scale`` and the ``covariance`` fields;
    default :data:`FIT_GRID`); the degenerate-direction inflation is not fitted.
    """
    grid = {**FIT_GRID, **(grid or {})}
    stacks = _stacks(datasets)
    names = list(grid)
    best = (1.0, CovarianceConfig(), np.inf)
    for values in itertools.product(*(grid[name] for name in names)):
        chosen = dict(zip(names, values, strict=True))
        scale = chosen.pop('scale')
        cfg = CovarianceConfig(**chosen)
        try:
            summaries = [nees_summary(_batch_nees(*stack, scale, cfg)) for stack in stacks]
        except np.linalg.LinAlgError:
            continue
        cost = calibration_cost(summaries)
        if cost < best[2]:
            best = (scale, cfg, cost)
    return best


def _stacks(datasets: dict[str, list[CovarianceSample]]) -> list[tuple[Any, ...]]:
    """Stack each data set's samples for :func:`_batch_nees`."""
    return [_stack(samples) for samples in datasets.values() if samples]


def _stack(samples: list[CovarianceSample]) -> tuple[Any, ...]:
    """Errors (K, 6), Hessian covariances (K, 6, 6), the inputs, the eigen, the keyframes."""
    covariances = np.array([s.hessian_covariance for s in samples], dtype=np.float64)
    return (
        np.array([s.error for s in samples], dtype=np.float64).reshape(-1, 6),
        covariances.reshape(-1, 6, 6),
        CovarianceInputs(
            np.array([s.distance for s in samples], dtype=np.float64),
            np.array([s.turn_deg for s in samples], dtype=np.float64),
            np.array([(s.correction_m, s.correction_deg) for s in samples]).reshape(-1, 2),
            np.array([s.gap_s for s in samples], dtype=np.float64),
            np.array([s.correction_vector[:3] for s in samples]).reshape(-1, 3),
            np.array([s.bend_m for s in samples], dtype=np.float64),
            np.array([s.residual_variance for s in samples], dtype=np.float64),
        ),
        hessian_eigen(covariances.reshape(-1, 6, 6)),
        KeyframeLinks.of(samples),
    )


def target_violation(values: list[np.ndarray], spread_weight: float = 0.1) -> float:
    """
    How far NEES values are from the target, smoothly (0: met with every mean at 6).

    Per data set: the distance of the mean outside :data:`TARGET_MEAN`, a tenth of the
    percentage points below :data:`TARGET_INSIDE_PCT` inside the 95 % bound, and
    ``spread_weight * |log(mean / 6)|``.
    """
    total, (low, high) = 0.0, TARGET_MEAN
    for nees in values:
        mean = float(np.mean(nees))
        if not np.isfinite(mean) or mean <= 0:
            return np.inf
        inside = 100.0 * float(np.mean(nees <= NEES_BOUND_95))
        total += max(low - mean, 0.0) + max(mean - high, 0.0)
        total += max(TARGET_INSIDE_PCT - inside, 0.0) / 10
        total += spread_weight * abs(np.log(mean / 6.0))
    return total


def fit_calibration_continuous(
    datasets: dict[str, list[CovarianceSample]],
    seed: int = 0,
    iterations: int = 150,
    start: tuple[float, CovarianceConfig] | None = None,
) -> tuple[float, CovarianceConfig, float]:
    """
    ``(scale, CovarianceConfig, violation)`` minimising :func:`target_violation`.

    A continuous search (scipy's differential evolution, ``popsize`` 15) within
    :data:`FIT_BOUNDS`, where the grid of :func:`fit_calibration` holds no calibration
    meeting every data set; ``start``: a calibration in the first population (the
    configured one), clipped to the bounds. The degenerate-direction inflation is not
    fitted.
    """
    from scipy.optimize import differential_evolution

    stacks = _stacks(datasets)
    names = list(FIT_BOUNDS)

    def calibration(x: np.ndarray) -> tuple[float, CovarianceConfig]:
        chosen = dict(zip(names, (float(v) for v in x), strict=True))
        return chosen.pop('scale'), CovarianceConfig(**chosen)

    def violation(x: np.ndarray) -> float:
        scale, cfg = calibration(x)
        try:
            return target_violation([_batch_nees(*stack, scale, cfg) for stack in stacks])
        except np.linalg.LinAlgError:
            return np.inf

    first = None
    if start is not None:
        values = [start[0] if n == 'scale' else getattr(start[1], n) for n in names]
        low, high = np.array(list(FIT_BOUNDS.values())).T
        share = np.clip((np.asarray(values) - low) / (high - low), 1e-9, 1.0 - 1e-9)
        first = low + share * (high - low)  # inside: scipy rounds a bound out of its box
    result = differential_evolution(
        violation,
        list(FIT_BOUNDS.values()),
        seed=seed,
        maxiter=iterations,
        popsize=15,
        tol=1e-8,
        polish=False,
        x0=first,
    )
    return (*calibration(result.x), float(result.fun))


#: The ranges :func:`fit_calibration_continuous` searches.
FIT_BOUNDS: dict[str, tuple[float, float]] = {
    'scale': (1.0, 40.0),
    'floor_translation': (0.0, 0.04),
    'floor_rotation': (0.0, 0.2),
    'per_metre_translation': (0.0, 0.005),
    'per_metre_rotation': (0.0, 0.03),
    'per_degree_translation': (0.0, 0.006),
    'per_degree_rotation': (0.0, 0.1),
    'per_correction_translation': (0.0, 2.0),
    'per_correction_rotation': (0.0, 0.5),
    'correction_free_translation': (0.0, 0.5),
    'correction_free_rotation': (0.0, 3.0),
    'correction_sweep': (0.02, 0.5),
    'rotation_floor_shape': (0.0, 1.0),
    'translation_floor_shape': (0.0, 1.0),
    'hessian_size_exponent': (0.0, 1.0),
    'floor_size_exponent': (0.0, 1.0),
    'along_correction': (0.0, 2.0),
    'per_bend_translation': (0.0, 0.2),
    'per_bend_rotation': (0.0, 1.0),
    'bend_free': (0.0, 3.0),
    'bend_window': (0.0, 0.5),
    'bend_relief': (0.0, 1.0),
    'residual_translation_exponent': (0.0, 2.0),
    'residual_rotation_exponent': (0.0, 2.0),
    'residual_min_factor': (0.1, 1.0),
    'residual_max_factor': (1.0, 10.0),
}


#: The values :func:`fit_calibration` tries by default.
FIT_GRID: dict[str, tuple[float, ...]] = {
    'scale': (2.0, 3.0, 5.0),
    'floor_translation': (0.005, 0.01, 0.015),
    'floor_rotation': (0.0, 0.02),
    'per_metre_translation': (0.0, 0.001, 0.002),
    'per_metre_rotation': (0.0,),
    'per_degree_translation': (0.0, 0.002, 0.004),
    'per_degree_rotation': (0.05, 0.1),
    'per_correction_translation': (0.0, 0.5, 0.75, 1.0),
    'per_correction_rotation': (0.0, 0.1, 0.2),
    'correction_free_translation': (0.1, 0.2),
    'correction_free_rotation': (0.5, 1.0),
    'correction_sweep': (0.1,),
    # the terms that follow the Hessian's size and the correction's direction: the defaults
    'hessian_size_exponent': (0.549,),
    'floor_size_exponent': (0.374,),
    'along_correction': (0.161,),
    'translation_floor_shape': (0.0,),
}


def chain_scans(pair_files: list[Any], period_s: float = 2.0) -> list[Any]:
    """Return the frames of a pair chain as scans ``period_s`` apart, at their chained poses."""
    from types import SimpleNamespace

    from mlsemreg_ros.datasets.pair_chain import chain_frames

    return [
        SimpleNamespace(
            xyz=frame.points,
            labels=frame.labels,
            stamp_ns=round(index * period_s * 1e9),
            point_times=None,
            intensity=None,
            pose=frame.T_0_frame,
            index=index,
        )
        for index, frame in enumerate(chain_frames(pair_files))
    ]


def save_samples(path: Any, samples: list[CovarianceSample]) -> None:
    """Write samples as ``errors`` (K, 6) and ``covariances`` (K, 6, 6) in an npz file."""
    np.savez(
        path,
        errors=np.array([s.error for s in samples]).reshape(-1, 6),
        covariances=np.array([s.hessian_covariance for s in samples]).reshape(-1, 6, 6),
        distances=np.array([s.distance for s in samples], dtype=np.float64),
        turns_deg=np.array([s.turn_deg for s in samples], dtype=np.float64),
        corrections=np.array(
            [(s.correction_m, s.correction_deg, s.gap_s) for s in samples], dtype=np.float64
        ).reshape(-1, 3),
        correction_vectors=np.array([s.correction_vector for s in samples]).reshape(-1, 6),
        scan_points=np.array([(s.scan_points, s.inliers) for s in samples]).reshape(-1, 2),
        sweep=np.array(
            [(s.bend_m, s.sweep_change_m, s.source) for s in samples], dtype=np.float64
        ).reshape(-1, 3),
        residuals=np.array(
            [(s.residual_variance, s.inlier_fraction) for s in samples], dtype=np.float64
        ).reshape(-1, 2),
        keyframes=np.array(
            [(s.keyframe_back, *s.relative) for s in samples], dtype=np.float64
        ).reshape(-1, 7),
    )


def load_samples(path: Any) -> list[CovarianceSample]:
    """Read samples written by :func:`save_samples`."""
    with np.load(path) as data:
        count = len(data['errors'])
        turns = data['turns_deg'] if 'turns_deg' in data.files else np.zeros(count)
        more = data['corrections'] if 'corrections' in data.files else np.zeros((count, 3))
        vectors = _column(data, 'correction_vectors', (count, 6))
        sizes = _column(data, 'scan_points', (count, 2)).astype(int)
        sweep = _column(data, 'sweep', (count, 3))
        residuals = _column(data, 'residuals', (count, 2))
        keyframes = _column(data, 'keyframes', (count, 7))
        rows = zip(
            data['errors'],
            data['covariances'],
            data['distances'],
            turns,
            more,
            vectors,
            sizes,
            sweep,
            residuals,
            keyframes,
            strict=True,
        )
        return [
            CovarianceSample(
                e,
                c,
                float(d),
                float(a),
                *(float(x) for x in m),
                v,
                *map(int, n),
                float(w[0]),
                float(w[1]),
                int(w[2]),
                float(r[0]),
                float(r[1]),
                int(k[0]),
                np.asarray(k[1:], dtype=np.float64),
            )
            for e, c, d, a, m, v, n, w, r, k in rows
        ]


def _column(data: Any, name: str, shape: tuple[int, int]) -> np.ndarray:
    """Return a column of a samples file (zeros in files written before it was kept)."""
    return np.asarray(data[name]) if name in data.files else np.zeros(shape)

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

"""The calibrated pose covariance and its NEES (core/alignment/covariance.py)."""

from __future__ import annotations

from dataclasses import replace

from mlsemreg_ros.core.alignment.alignment import Alignment
from mlsemreg_ros.core.alignment.covariance import (
    calibrated_covariance,
    calibrated_covariances,
    CovarianceConfig,
    CovarianceInputs,
    degenerate_inflation,
    floor_shape,
    MAX_FLOOR_STRETCH,
    motion_size,
    no_calibration,
    REFERENCE_RESIDUAL,
    REFERENCE_SIGMAS,
)
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry import Odometry
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.datasets.pairs import list_pairs, Pair, save_pair
from mlsemreg_ros.datasets.synthetic_scene import motion, scan_at, street_scene
from mlsemreg_ros.evaluation.covariance_calibration import (
    chain_scans,
    CovarianceSample,
    fit_calibration,
    fit_calibration_continuous,
    FIT_GRID,
    load_samples,
    meets_target,
    NEES_BOUND_95,
    nees_summary,
    nees_values,
    save_samples,
    source_code,
    SOURCES,
    stream_samples,
    target_violation,
)
import numpy as np
import pytest

#: No calibration: the Hessian covariance times the scale.
OFF = no_calibration()


def test_the_default_calibration_only_scales() -> None:
    hessian = np.diag([1e-6, 2e-6, 3e-6, 1e-8, 2e-8, 3e-8])
    assert np.allclose(calibrated_covariance(hessian, 7.0, OFF), 7.0 * hessian)


def test_the_floor_grows_with_distance_and_turn() -> None:
    cfg = CovarianceConfig(
        floor_translation=0.01,
        floor_rotation=0.1,
        per_metre_translation=0.002,
        per_metre_rotation=0.01,
        per_degree_translation=0.05,
        per_degree_rotation=0.2,
        degenerate_ratio=0.0,
    )
    covariance = calibrated_covariance(np.zeros((6, 6)), 1.0, cfg, distance=10.0, turn_deg=2.0)
    sigma_t = 0.01 + 0.002 * 10 + 0.05 * 2
    sigma_r = np.radians(0.1 + 0.01 * 10 + 0.2 * 2)
    assert np.allclose(np.diag(covariance), [sigma_t**2] * 3 + [sigma_r**2] * 3)
    assert np.allclose(motion_size(motion(30.0, (3.0, 4.0, 0.0))), (5.0, 30.0))


def test_a_weak_direction_of_the_hessian_is_inflated_along_it_only() -> None:
    """A corridor: translation along x barely constrained (variance 100 times the others)."""
    rotation = motion(30.0, (0, 0, 0))[:3, :3]
    block = rotation @ np.diag([1e-2, 1e-4, 1e-4]) @ rotation.T
    covariance = np.zeros((6, 6))
    covariance[:3, :3] = block
    covariance[3:, 3:] = np.eye(3) * 1e-8
    cfg = replace(OFF, degenerate_ratio=10.0, degenerate_translation=0.5)
    inflation = degenerate_inflation(covariance, cfg)
    weak = rotation[:, 0]
    assert np.allclose(inflation[:3, :3], 0.25 * np.outer(weak, weak), atol=1e-9)
    assert np.allclose(inflation[3:, 3:], 0.0)  # the rotation block is well conditioned
    assert np.allclose(degenerate_inflation(covariance, OFF), 0.0)
    # the default threshold (100) inflates it, and leaves a milder one (ratio 50) alone
    assert np.allclose(
        degenerate_inflation(covariance, CovarianceConfig())[:3, :3], inflation[:3, :3]
    )
    covariance[:3, :3] = rotation @ np.diag([5e-3, 1e-4, 1e-4]) @ rotation.T
    assert np.allclose(degenerate_inflation(covariance, CovarianceConfig()), 0.0)


def test_the_rotation_floor_follows_the_shape_of_the_hessian() -> None:
    """A roll 4 times weaker (in variance) than pitch and yaw gets 4^(1/3) of the floor."""
    rotation = motion(30.0, (0, 0, 0))[:3, :3]  # the block in turned axes: the floor turns too
    covariance = np.zeros((6, 6))
    covariance[:3, :3] = np.eye(3) * 1e-6
    covariance[3:, 3:] = rotation @ np.diag([4e-8, 1e-8, 1e-8]) @ rotation.T
    floor_only = replace(OFF, floor_rotation=0.1, rotation_floor_shape=0.5)
    sigma_r2 = np.radians(0.1) ** 2
    shaped = calibrated_covariance(covariance, 1.0, floor_only)[3:, 3:] - covariance[3:, 3:]
    weak, strong = rotation[:, 0], rotation[:, 1]
    assert np.isclose(weak @ shaped @ weak, sigma_r2 * 4 ** (1 / 3))
    assert np.isclose(strong @ shaped @ strong, sigma_r2 * 4 ** (-1 / 6))
    assert np.isclose(np.linalg.det(shaped), sigma_r2**3)  # the floor's volume is kept
    isotropic = replace(floor_only, rotation_floor_shape=0.0)
    plain = calibrated_covariance(covariance, 1.0, isotropic)[3:, 3:] - covariance[3:, 3:]
    assert np.allclose(plain, sigma_r2 * np.eye(3))
    # the translation floor stays isotropic; a zero or non-finite block gives the identity
    assert np.allclose(floor_shape(np.zeros((3, 3)), 0.5), np.eye(3))
    assert np.allclose(floor_shape(np.full((3, 3), np.nan), 0.5), np.eye(3))
    # a nearly degenerate block is stretched at most MAX_FLOOR_STRETCH along its weak axis
    stretched = floor_shape(np.diag([1.0, 1e-12, 1e-12]), 1.0)
    assert np.isclose(stretched[0, 0], MAX_FLOOR_STRETCH)
    # stacked blocks give what each block gives alone
    stack = np.stack([covariance[3:, 3:], np.eye(3) * 1e-8])
    assert np.allclose(floor_shape(stack, 0.5)[0], floor_shape(covariance[3:, 3:], 0.5))
    assert np.allclose(floor_shape(stack, 0.5)[1], np.eye(3))


@pytest.mark.parametrize('seed', [0, 1])
def test_errors_drawn_from_the_true_covariance_have_a_chi_square_nees(seed: int) -> None:
    """The Hessian claims 20 times too little; the scale 20 calibration makes it consistent."""
    rng = np.random.default_rng(seed)
    samples = []
    for _ in range(400):
        axes = np.linalg.qr(rng.normal(size=(6, 6)))[0]
        truth = axes @ np.diag(rng.uniform(1e-5, 1e-3, 6)) @ axes.T
        error = rng.multivariate_normal(np.zeros(6), truth)
        samples.append(CovarianceSample(error, truth / 20.0))
    before = nees_summary(nees_values(samples, 1.0, OFF))
    after = nees_summary(nees_values(samples, 20.0, OFF))
    assert before['nees_mean'] > 80.0
    assert 5.0 < after['nees_mean'] < 7.0
    assert 92.0 < after['inside_95_pct'] < 98.0 and NEES_BOUND_95 == pytest.approx(12.59, 0.01)
    scale, cfg, _ = fit_calibration(
        {'all': samples},
        {
            'scale': (1.0, 5.0, 20.0, 80.0),
            'floor_translation': (0.0, 0.1),
            'floor_rotation': (0.0,),
            'per_metre_translation': (0.0,),
            'per_metre_rotation': (0.0,),
            'per_degree_translation': (0.0,),
            'per_degree_rotation': (0.0,),
            'per_correction_translation': (0.0,),
            'per_correction_rotation': (0.0,),
            'correction_free_translation': (0.0,),
            'correction_free_rotation': (0.0,),
            'correction_sweep': (0.1,),
            'hessian_size_exponent': (0.0,),
            'floor_size_exponent': (0.0,),
            'along_correction': (0.0,),
        },
    )
    assert scale == 20.0 and cfg.floor_translation == 0.0


def test_the_continuous_fit_meets_the_target_on_two_data_sets() -> None:
    """Hessians 4 times too small, errors growing with the distance: both sets met."""
    rng = np.random.default_rng(3)
    near, far = [], []
    for samples, distance in ((near, 1.0), (far, 10.0)):
        for _ in range(200):
            truth = np.diag([1e-4] * 3 + [1e-6] * 3) * (1.0 + 0.5 * distance)
            error = rng.multivariate_normal(np.zeros(6), truth)
            samples.append(CovarianceSample(error, truth / 4.0, distance))
    datasets = {'near': near, 'far': far}
    scale, cfg, _ = fit_calibration_continuous(datasets, iterations=40)
    for samples in datasets.values():
        summary = nees_summary(nees_values(samples, scale, cfg))
        assert 3.0 <= summary['nees_mean'] <= 12.0, (scale, cfg, summary)
        assert summary['inside_95_pct'] >= 85.0, summary
    before = nees_summary(nees_values(far, 1.0, OFF))
    assert before['nees_mean'] > 12.0  # the fit had something to do


def test_samples_survive_a_round_trip(tmp_path) -> None:
    samples = [CovarianceSample(np.arange(6.0), np.eye(6), 3.0, 4.0, 0.5, 2.0, 1.0)]
    save_samples(tmp_path / 's.npz', samples)
    (back,) = load_samples(tmp_path / 's.npz')
    assert np.array_equal(back.error, np.arange(6.0)) and (back.distance, back.turn_deg) == (3, 4)
    assert (back.correction_m, back.correction_deg, back.gap_s) == (0.5, 2.0, 1.0)


def test_a_correction_counts_by_the_share_of_it_within_one_sweep() -> None:
    """3 m off after 1 s bends a 0.1 s sweep as 0.3 m off after 0.1 s; below the free part: 0."""
    cfg = replace(
        OFF,
        per_correction_translation=0.75,
        per_correction_rotation=0.1,
        correction_free_translation=0.1,
        correction_free_rotation=0.5,
        correction_sweep=0.1,
    )
    zero = np.zeros((6, 6))
    stride_10 = calibrated_covariance(zero, 1.0, cfg, correction=(3.0, 20.0), horizon_s=1.0)
    stride_1 = calibrated_covariance(zero, 1.0, cfg, correction=(0.3, 2.0), horizon_s=0.1)
    sigma_t, sigma_r = 0.75 * (0.3 - 0.1), np.radians(0.1 * (2.0 - 0.5))
    assert np.allclose(stride_10, stride_1)
    assert np.allclose(np.diag(stride_1), [sigma_t**2] * 3 + [sigma_r**2] * 3)
    # a horizon shorter than the sweep, or unknown (0), counts the correction whole
    assert np.allclose(
        calibrated_covariance(zero, 1.0, cfg, correction=(0.3, 2.0), horizon_s=0.05), stride_1
    )
    assert np.allclose(calibrated_covariance(zero, 1.0, cfg, correction=(0.3, 2.0)), stride_1)
    small = calibrated_covariance(zero, 1.0, cfg, correction=(0.9, 4.0), horizon_s=1.0)
    assert np.allclose(small, 0.0)  # 0.09 m and 0.4 deg within a sweep: inside the free part
    samples = [CovarianceSample(np.full(6, 0.01), np.eye(6) * 1e-6, 0, 0, 3.0, 20.0, 1.0)]
    assert nees_values(samples, 1.0, cfg)[0] < nees_values(samples, 1.0, OFF)[0] / 10


def test_a_pair_chain_streams_into_samples_with_its_corrections(tmp_path) -> None:
    """Four scans of a street 1.5 m apart as chained pair files, streamed 2 s apart."""
    world, labels = street_scene(seed=3)
    poses = [motion(0.0, (1.5 * k, 0.0, 0.0)) for k in range(4)]
    scans = [scan_at(world, labels, p, seed=20 + k, max_points=15000) for k, p in enumerate(poses)]
    for k in range(3):
        (src, label_src), (dst, label_dst) = scans[k], scans[k + 1]
        T_dst_src = np.linalg.solve(poses[k + 1], poses[k])
        pair = Pair(f'{k:06d}', src, label_src, dst, label_dst, T_dst_src)
        save_pair(tmp_path / f'{k:06d}.npz', pair)
    frames = chain_scans(list_pairs(tmp_path))
    assert [f.stamp_ns for f in frames] == [0, 2_000_000_000, 4_000_000_000, 6_000_000_000]
    samples = stream_samples(frames, RegistrationConfig())
    assert len(samples) == 3
    assert all(s.gap_s == pytest.approx(2.0) for s in samples)
    assert all(np.linalg.norm(s.error[:3]) < 0.1 for s in samples)
    assert samples[0].correction_m == 0.0  # the second scan has no prediction yet
    assert all(np.isfinite(s.correction_m) for s in samples[1:])


def test_the_odometry_publishes_the_calibrated_covariance() -> None:
    world, labels = street_scene(seed=3)
    off = {f'covariance.{k}': 0.0 for k in vars(OFF)}
    floor = {**off, 'covariance.floor_translation': 0.05, 'covariance.floor_rotation': 0.5}
    steps = {}
    for name, overrides in (('plain', off), ('calibrated', floor)):
        odometry = Odometry(Registration(RegistrationConfig().replace(overrides)))
        for k in range(3):
            pose = motion(0.0, (1.0 * k, 0.0, 0.0))
            points, scan_labels = scan_at(world, labels, pose, seed=10 + k, max_points=15000)
            step = odometry.process(points, scan_labels, k * 100_000_000)
        assert step.accepted
        steps[name] = step
    plain, calibrated = steps['plain'].frame_covariance, steps['calibrated'].frame_covariance
    added = np.diag([0.05**2] * 3 + [np.radians(0.5) ** 2] * 3)
    assert np.allclose(calibrated, plain + added, rtol=1e-3, atol=1e-9)


def test_the_translation_floor_follows_the_shape_of_the_hessian() -> None:
    """Along a straight road the Hessian's weak translation gets the floor's larger part."""
    heading = motion(25.0, (0, 0, 0))[:3, :3]
    covariance = np.zeros((6, 6))
    covariance[:3, :3] = heading @ np.diag([8e-6, 1e-6, 1e-6]) @ heading.T
    covariance[3:, 3:] = np.eye(3) * 1e-8
    cfg = replace(OFF, floor_translation=0.02, translation_floor_shape=0.5)
    added = calibrated_covariance(covariance, 1.0, cfg)[:3, :3] - covariance[:3, :3]
    along, across = heading[:, 0], heading[:, 1]
    assert np.isclose(along @ added @ along, 0.02**2 * 8 ** (1 / 3))
    assert np.isclose(across @ added @ across, 0.02**2 * 8 ** (-1 / 6))
    assert np.isclose(np.linalg.det(added), (0.02**2) ** 3)
    assert np.allclose(calibrated_covariance(covariance, 1.0, OFF), covariance)


def test_a_correction_adds_variance_along_its_direction_only() -> None:
    """The error of a scan deskewed by a prediction 2 m off at stride 10 lies along it."""
    cfg = replace(OFF, along_correction=0.5, correction_sweep=0.1)
    direction = np.array([2.0, 0.5, 0.0])
    zero = np.zeros((6, 6))
    added = calibrated_covariance(
        zero, 1.0, cfg, correction=(2.06, 0.0), horizon_s=1.0, correction_direction=direction
    )
    unit = direction / np.linalg.norm(direction)
    sideways = np.array([-unit[1], unit[0], 0.0])
    assert np.isclose(unit @ added[:3, :3] @ unit, (0.5 * 0.1 * np.linalg.norm(direction)) ** 2)
    assert np.isclose(sideways @ added[:3, :3] @ sideways, 0.0)
    assert np.allclose(added[3:, :], 0.0)
    # without a direction (a pair, the first scans) the term adds nothing
    assert np.allclose(calibrated_covariance(zero, 1.0, cfg, correction=(2.06, 0.0)), 0.0)


def test_a_jerk_between_scans_adds_variance_along_it_and_for_a_missed_turn() -> None:
    """
    A hand's 0.3 m correction over 0.3 s (stride 3) counts whole.

    One that replaced the prediction (a 40 deg turn) or came after 1 s counts less or not at all.
    """
    cfg = replace(
        OFF,
        jerk_along=0.5,
        jerk_free=0.1,
        jerk_window=0.3,
        jerk_per_degree=0.02,
        jerk_free_turn=2.0,
        jerk_max_turn=30.0,
    )
    direction = np.array([0.0, 0.3, 0.0])
    zero = np.zeros((6, 6))

    def added(turn_deg: float, horizon_s: float) -> np.ndarray:
        return calibrated_covariance(
            zero,
            1.0,
            cfg,
            correction=(0.3, turn_deg),
            horizon_s=horizon_s,
            correction_direction=direction,
        )

    along = added(0.0, 0.3)
    assert np.isclose(along[1, 1], (0.5 * (0.3 - 0.1)) ** 2)
    assert np.isclose(along[0, 0], 0.0) and np.allclose(along[3:, :], 0.0)
    turned = added(12.0, 0.3)  # a turn the prediction missed: every translation axis
    assert np.isclose(turned[0, 0], (0.02 * (12.0 - 2.0)) ** 2)
    assert np.isclose(turned[1, 1], (0.5 * 0.2) ** 2 + (0.02 * 10.0) ** 2)
    assert np.allclose(added(40.0, 0.3), 0.0)  # the registration replaced the prediction
    assert np.allclose(added(0.0, 1.0), 0.0)  # 0.3 m after 1 s: 0.09 m, within jerk_free


def test_a_tighter_hessian_gets_a_larger_scale_with_the_size_exponent() -> None:
    """A block 100 times smaller in variance is scaled up 100^b: the NEES follows less the size."""
    reference_t, reference_r = REFERENCE_SIGMAS
    at_reference = np.diag([reference_t**2] * 3 + [reference_r**2] * 3)
    cfg = replace(OFF, hessian_size_exponent=0.5)
    assert np.allclose(calibrated_covariance(at_reference, 1.0, cfg), at_reference)
    tight = at_reference / 100.0
    assert np.allclose(calibrated_covariance(tight, 1.0, cfg), tight * 10.0)
    loose = at_reference * 4.0
    assert np.allclose(calibrated_covariance(loose, 1.0, cfg), loose / 2.0)
    # the scale counts in the size: scale 4 on the reference is the loose block
    assert np.allclose(calibrated_covariance(at_reference, 4.0, cfg), loose / 2.0)
    # the cross terms follow both blocks' factors, so the result stays positive definite
    rng = np.random.default_rng(2)
    mixed = rng.normal(size=(6, 6))
    mixed = mixed @ mixed.T * 1e-7
    assert np.all(np.linalg.eigvalsh(calibrated_covariance(mixed, 1.0, cfg)) > 0)


def test_stacked_samples_calibrate_as_each_one_alone() -> None:
    """calibrated_covariances (the fit's) gives calibrated_covariance (the odometry's)."""
    rng = np.random.default_rng(5)
    cfg = replace(
        CovarianceConfig(),
        hessian_size_exponent=0.3,
        translation_floor_shape=0.4,
        along_correction=0.7,
        degenerate_ratio=20.0,
    )
    covariances, rows = [], []
    for _ in range(6):
        axes = np.linalg.qr(rng.normal(size=(6, 6)))[0]
        covariances.append(axes @ np.diag(rng.uniform(1e-8, 1e-5, 6)) @ axes.T)
        rows.append((*rng.uniform(0, 10, 2), *rng.uniform(0, 2, 2), rng.choice([0.0, 0.1, 1.0])))
    directions = rng.normal(size=(6, 3))
    inputs = CovarianceInputs(
        *(np.array([row[i] for row in rows]) for i in (0, 1)),
        np.array([row[2:4] for row in rows]),
        np.array([row[4] for row in rows]),
        directions,
    )
    stacked = calibrated_covariances(np.array(covariances), 3.0, cfg, inputs)
    for k, (covariance, row) in enumerate(zip(covariances, rows, strict=True)):
        alone = calibrated_covariance(
            covariance, 3.0, cfg, *row[:2], row[2:4], row[4], correction_direction=directions[k]
        )
        assert np.allclose(stacked[k], alone, rtol=1e-12, atol=1e-20)


def test_samples_keep_the_correction_direction_and_the_scan_size(tmp_path) -> None:
    vector = np.array([0.3, -0.1, 0.0, 0.0, 0.0, 0.01])
    sample = CovarianceSample(np.ones(6), np.eye(6), 1.0, 2.0, 0.32, 0.6, 0.1, vector, 23000, 2100)
    save_samples(tmp_path / 's.npz', [sample])
    (back,) = load_samples(tmp_path / 's.npz')
    assert np.array_equal(back.correction_vector, vector)
    assert (back.scan_points, back.inliers) == (23000, 2100)
    # a file written before they were kept loads with zeros
    np.savez(tmp_path / 'old.npz', errors=np.ones((1, 6)), covariances=np.eye(6)[None],
             distances=np.ones(1))  # fmt: skip
    (old,) = load_samples(tmp_path / 'old.npz')
    assert np.array_equal(old.correction_vector, np.zeros(6)) and old.scan_points == 0


def test_the_fit_finds_the_size_exponent_two_sensors_need() -> None:
    """
    A dense sensor's Hessian claims 100 times too little, a sparse one's 10 times.

    The sparse Hessian covariance is 100 times the dense one, so no single scale meets both
    (it would leave one at a mean of 60 or 0.6), while ``hessian_size_exponent`` 0.5 does:
    the size is the scaled block's, so the factor is ``s^(1 - b) (g_H / g_ref)^-b``, 100 and
    10 with ``s`` 1000.
    """
    rng = np.random.default_rng(4)
    reference_t, reference_r = REFERENCE_SIGMAS
    unit = np.diag([reference_t**2] * 3 + [reference_r**2] * 3)
    datasets = {}
    for name, hessian, claims_too_little in (
        ('dense', unit / 10, 100.0),
        ('sparse', unit * 10, 10.0),
    ):
        truth = hessian * claims_too_little
        errors = rng.multivariate_normal(np.zeros(6), truth, size=300)
        datasets[name] = [CovarianceSample(error, hessian) for error in errors]
    grid = {name: (0.0,) for name in FIT_GRID if name != 'scale'}
    grid |= {'scale': (1.0, 10.0, 30.0, 100.0, 1000.0), 'correction_sweep': (0.1,)}
    scale, cfg, _ = fit_calibration(datasets, grid)
    assert cfg.hessian_size_exponent == 0.0
    summaries = [nees_summary(nees_values(s, scale, cfg)) for s in datasets.values()]
    assert not all(meets_target(summary) for summary in summaries)
    grid['hessian_size_exponent'] = (0.0, 0.25, 0.5, 0.75)
    scale, cfg, _ = fit_calibration(datasets, grid)
    assert (scale, cfg.hessian_size_exponent) == (1000.0, 0.5)
    for samples in datasets.values():
        assert meets_target(nees_summary(nees_values(samples, scale, cfg)))


def test_the_continuous_fit_is_no_worse_than_its_start() -> None:
    """The configured calibration is in the first population: a short search keeps or beats it."""
    rng = np.random.default_rng(6)
    truth = np.diag([1e-4] * 3 + [1e-6] * 3)
    errors = rng.multivariate_normal(np.zeros(6), truth, size=100)
    datasets = {'set': [CovarianceSample(error, truth / 30.0, 1.0) for error in errors]}
    start = (30.0, OFF)
    start_violation = target_violation([nees_values(datasets['set'], *start)])
    _, _, violation = fit_calibration_continuous(datasets, iterations=2, start=start)
    assert violation <= start_violation + 1e-6  # the start is nudged 1e-9 inside its bounds


def test_a_bent_scan_gets_the_bend_terms_beyond_the_free_part() -> None:
    """A 4 m bend counts whole at 0.1 s and times 0.3 at 1 s; below bend_free nothing."""
    cfg = replace(
        OFF, per_bend_translation=0.1, per_bend_rotation=0.2, bend_free=0.5, bend_window=0.3
    )
    zero = np.zeros((6, 6))
    close = calibrated_covariance(zero, 1.0, cfg, horizon_s=0.1, bend_m=4.0)
    sigma_t, sigma_r = 0.1 * (4.0 - 0.5), np.radians(0.2 * (4.0 - 0.5))
    assert np.allclose(np.diag(close), [sigma_t**2] * 3 + [sigma_r**2] * 3)
    far = calibrated_covariance(zero, 1.0, cfg, horizon_s=1.0, bend_m=4.0)
    assert np.allclose(np.diag(far)[:3], (0.1 * (0.3 * 4.0 - 0.5)) ** 2)
    assert np.allclose(calibrated_covariance(zero, 1.0, cfg, horizon_s=1.0, bend_m=1.5), 0.0)
    assert np.allclose(calibrated_covariance(zero, 1.0, cfg, horizon_s=0.1), 0.0)  # not bent


def test_the_bend_relief_takes_the_correction_terms_off_a_bent_scan_only() -> None:
    """The sweep alignment replaced the deskew a wrong prediction gave: its terms shrink."""
    cfg = replace(
        OFF,
        per_correction_translation=1.0,
        correction_sweep=0.0,
        along_correction=0.5,
        bend_relief=0.75,
    )
    zero, direction = np.zeros((6, 6)), np.array([0.4, 0.0, 0.0])
    kwargs = {'correction': (0.4, 0.0), 'correction_direction': direction}
    straight = calibrated_covariance(zero, 1.0, cfg, **kwargs)
    bent = calibrated_covariance(zero, 1.0, cfg, bend_m=2.0, **kwargs)
    assert np.allclose(straight[:3, :3], np.diag([0.4**2 + 0.2**2, 0.4**2, 0.4**2]))
    assert np.allclose(bent, straight * 0.25**2)
    unrelieved = calibrated_covariance(
        zero, 1.0, replace(cfg, bend_relief=0.0), bend_m=2.0, **kwargs
    )
    assert np.allclose(unrelieved, straight)


def test_the_floors_follow_the_residual_within_their_bounds() -> None:
    """Residual 4 x the reference: floors x 4 (exponent 1), x 2 (0.5); the Hessian part kept."""
    cfg = replace(
        OFF,
        floor_translation=0.01,
        floor_rotation=0.1,
        residual_translation_exponent=1.0,
        residual_rotation_exponent=0.5,
        residual_min_factor=0.01,
        residual_max_factor=100.0,
    )
    hessian = np.diag([1e-4] * 3 + [1e-6] * 3)
    plain = calibrated_covariance(hessian, 2.0, cfg)  # residual unknown: floors as they are
    floors = np.array([1e-4] * 3 + [np.radians(0.1) ** 2] * 3)
    assert np.allclose(np.diag(plain), np.diag(2.0 * hessian) + floors)
    loose = calibrated_covariance(hessian, 2.0, cfg, residual_variance=4 * REFERENCE_RESIDUAL)
    assert np.allclose(np.diag(loose) - np.diag(2.0 * hessian), floors * [4, 4, 4, 2, 2, 2])
    tight = calibrated_covariance(hessian, 2.0, cfg, residual_variance=REFERENCE_RESIDUAL / 4)
    assert np.allclose(np.diag(tight)[:3] - 2e-4, 0.25e-4)
    off = calibrated_covariance(hessian, 2.0, OFF, residual_variance=4 * REFERENCE_RESIDUAL)
    assert np.allclose(off, 2.0 * hessian)
    capped = replace(cfg, residual_min_factor=0.5, residual_max_factor=1.0)
    kept = calibrated_covariance(hessian, 2.0, capped, residual_variance=4 * REFERENCE_RESIDUAL)
    assert np.allclose(kept, plain)  # a loose fit keeps the floors (the defaults)
    tightest = calibrated_covariance(
        hessian, 2.0, capped, residual_variance=REFERENCE_RESIDUAL / 9
    )
    assert np.allclose(np.diag(tightest)[:3] - 2e-4, 0.5e-4)  # at most halved


def test_the_residual_variance_is_the_hessians_scale() -> None:
    """``2E / (n - 6)``, the factor of ``inv(H)`` in the covariance; 0 without a dof."""
    hessian = np.diag([4.0, 4.0, 4.0, 1.0, 1.0, 1.0])
    fit = Alignment(np.eye(4), np.eye(4), True, 3, 16, 20, 3.0, hessian)
    assert fit.residual_variance == pytest.approx(0.6)
    assert np.allclose(np.diag(fit.covariance(1.0)), 0.6 * np.array([1, 1, 1, 0.25, 0.25, 0.25]))
    assert Alignment(np.eye(4), np.eye(4), True, 3, 6, 20, 3.0, hessian).residual_variance == 0


def test_samples_keep_the_bend_and_the_source(tmp_path) -> None:
    sample = CovarianceSample(np.ones(6), np.eye(6), 1.0, 2.0, bend_m=3.5, sweep_change_m=3.5)
    sample.source = source_code('prediction+global')
    save_samples(tmp_path / 's.npz', [sample, CovarianceSample(np.ones(6), np.eye(6))])
    bent, plain = load_samples(tmp_path / 's.npz')
    assert (bent.bend_m, bent.sweep_change_m, SOURCES[bent.source]) == (
        3.5,
        3.5,
        'prediction+global',
    )
    assert (plain.bend_m, plain.source) == (0.0, 0)
    tight = CovarianceSample(np.ones(6), np.eye(6), residual_variance=0.1, inlier_fraction=0.7)
    save_samples(tmp_path / 'r.npz', [tight])
    (kept,) = load_samples(tmp_path / 'r.npz')
    assert (kept.residual_variance, kept.inlier_fraction) == (0.1, 0.7)
    cfg = replace(OFF, floor_translation=1.0, residual_min_factor=0.5, residual_max_factor=1.0)
    values = nees_values([kept], 1.0, cfg)
    closer = nees_values([kept], 1.0, replace(cfg, residual_translation_exponent=1.0))
    assert closer[0] > values[0]  # the residual reaches the covariance
    values = nees_values([bent], 1.0, replace(OFF, per_bend_translation=1.0))
    assert values[0] < nees_values([plain], 1.0, OFF)[0]  # the bend reaches the covariance

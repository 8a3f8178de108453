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

"""The compiled kernels of the refused path give what the NumPy code gives."""

from __future__ import annotations

from dataclasses import replace

from hypothesis import example, given, settings
from hypothesis import strategies as st
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.estimation import bev_search
from mlsemreg_ros.core.estimation.covisibility import RangeImage
from mlsemreg_ros.core.estimation.guided import guided_correspondences
from mlsemreg_ros.core.estimation.verification import LabelCompatibility, refine_starts
from mlsemreg_ros.core.features import kernels
from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.results import Landmarks, PreparedScan
from mlsemreg_ros.core.rigid import apply_transform
from mlsemreg_ros.datasets.synthetic_scene import motion
import numpy as np
import pytest
from scipy import fft
from scipy.spatial.transform import Rotation

pytestmark = pytest.mark.skipif(not kernels.AVAILABLE, reason='numba is not installed')

LABELS = LabelMap.load()


def _keypoint_scan(
    keypoints: np.ndarray, descriptors: np.ndarray, labels: np.ndarray
) -> PreparedScan:
    """Make a scan whose points are its keypoints (labels per keypoint)."""
    return PreparedScan(
        keypoints,
        labels.astype(np.int32),
        keypoints,
        np.arange(len(keypoints), dtype=np.int64),
        descriptors.astype(np.float32),
        np.zeros((len(keypoints), LABELS.num_classes), bool),
        Landmarks.empty(),
    )


def _scans(seed: int, count: int = 600) -> tuple[PreparedScan, PreparedScan, np.ndarray]:
    """Make two keypoint scans: a third share places and descriptors under a pose."""
    rng = np.random.default_rng(seed)
    truth = motion(rng.uniform(-180, 180), (rng.uniform(-10, 10), rng.uniform(-10, 10), 0.2))
    source = rng.uniform(-30, 30, (count, 3)) * [1, 1, 0.1]
    descriptors = rng.normal(size=(count, 16))
    labels = rng.integers(0, 4, count)
    target = rng.uniform(-30, 30, (count, 3)) * [1, 1, 0.1]
    target_descriptors = rng.normal(size=(count, 16))
    target_labels = rng.integers(0, 4, count)
    shared = rng.choice(count, count // 3, replace=False)
    target[shared] = apply_transform(truth, source[shared]) + rng.normal(0, 0.05, (len(shared), 3))
    target_descriptors[shared] = descriptors[shared] + rng.normal(0, 0.1, (len(shared), 16))
    target_labels[shared] = labels[shared]
    return (
        _keypoint_scan(source, descriptors, labels),
        _keypoint_scan(target, target_descriptors, target_labels),
        truth,
    )


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), radius=st.sampled_from([0.5, 2.0, 3.0, 7.5]))
def test_guided_matches_are_the_numpy_matches(seed, radius):
    source, target, truth = _scans(seed)
    compatible = np.eye(4, dtype=bool)
    compatible[1, 2] = compatible[2, 1] = True
    rules = LabelCompatibility(compatible, np.ones(4, dtype=bool))
    for labels in (None, rules):
        for pose in (truth, motion(10.0, (2.0, 0.0, 0.0))):
            slow = guided_correspondences(source, target, pose, radius, labels, compiled=False)
            fast = guided_correspondences(source, target, pose, radius, labels, compiled=True)
            np.testing.assert_array_equal(fast.source, slow.source)
            np.testing.assert_array_equal(fast.target, slow.target)
            np.testing.assert_allclose(fast.distance, slow.distance, rtol=1e-6)


def test_guided_matching_at_the_true_pose_finds_the_shared_places():
    source, target, truth = _scans(7)
    found = guided_correspondences(source, target, truth, 0.5, compiled=True)
    right = np.linalg.norm(
        apply_transform(truth, source.keypoints[found.source]) - target.keypoints[found.target],
        axis=1,
    )
    assert np.count_nonzero(right < 0.3) >= 180  # of the 200 shared places


def test_a_label_outside_the_rules_is_never_matched():
    source, target, truth = _scans(3, count=200)
    source.labels[:] = 99  # outside the 4 x 4 rules
    rules = LabelCompatibility(np.ones((4, 4), dtype=bool), np.ones(4, dtype=bool))
    assert len(guided_correspondences(source, target, truth, 3.0, rules, compiled=True)) == 0
    assert len(guided_correspondences(source, target, truth, 3.0, rules, compiled=False)) == 0


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 10_000))
@example(seed=4270)  # 9 of the 12 near starts converge (10-12 on 201 other seeds)
def test_refined_starts_are_the_numpy_refinements(seed):
    rng = np.random.default_rng(seed)
    count = 1500
    truth = motion(rng.uniform(-180, 180), tuple(rng.uniform(-20, 20, 3)))
    src = rng.uniform(-40, 40, (count, 3))
    dst = rng.uniform(-40, 40, (count, 3))
    inliers = rng.choice(count, 80, replace=False)
    dst[inliers] = apply_transform(truth, src[inliers]) + rng.normal(0, 0.1, (80, 3))
    src[rng.integers(count)] = np.nan  # non-finite pairs are ignored
    starts = np.stack(
        [truth @ motion(rng.normal(0, 2), tuple(rng.normal(0, 0.5, 3))) for _ in range(12)]
        + [motion(rng.uniform(-180, 180), tuple(rng.uniform(-20, 20, 3))) for _ in range(4)]
    )
    estimator = RegistrationConfig().estimator
    slow = refine_starts(starts, src, dst, estimator, compiled=False)
    fast = refine_starts(starts, src, dst, estimator, compiled=True)
    np.testing.assert_allclose(fast, slow, atol=1e-9)
    near_errors = np.abs(fast[:12, :3, 3] - truth[:3, 3]).max(axis=1)
    assert np.count_nonzero(near_errors < 0.2) >= 8  # most near starts converge


def test_the_search_on_the_reachable_block_is_the_full_grid_search():
    """The local maxima on the reachable shifts alone: the same peaks as on the full grid."""
    rng = np.random.default_rng(5)
    points = rng.uniform(-40, 40, (4000, 3))
    labels = rng.choice([13, 15, 18], 4000).astype(np.int32)
    T = motion(17.0, (11.0, -6.0, 0.0))
    moved = apply_transform(np.linalg.inv(T), points)
    lookup = bev_search.channel_lookup(LABELS, RegistrationConfig().bev_search)
    search = replace(RegistrationConfig().bev_search, max_translation=20.0, radius=30.0)
    grid = bev_search.BevGrid.make(search.cell_size, search.radius, search.max_translation)
    source_channel = bev_search._channels(labels, lookup)
    correlator = bev_search.Correlator(
        moved[:, :2], source_channel, points[:, :2], source_channel, grid, 3
    )
    # 0, 90, 180 and 270 deg, and 15 and 105 deg: read from one transform each (quarter turns)
    yaws = np.array([0.0, 15.0, 17.0, 90.0, 105.0, 180.0, 270.0])
    peaks = correlator.peaks(yaws, 5)
    # the full grid: every shift, unreachable ones at -inf, local maxima with wrap-around
    expected = []
    for yaw in yaws:
        rotation = Rotation.from_euler('z', yaw, degrees=True).as_matrix()[:2, :2]
        source = bev_search.occupancy(
            moved[:, :2] @ rotation.T, source_channel, grid, 3, grid.radius
        )
        spectrum = np.conj(fft.rfft2(source)) * correlator.target_spectrum
        full = fft.irfft2(spectrum.sum(axis=0), s=(grid.size, grid.size))
        shift = correlator.shift
        reachable = np.abs(shift) <= grid.max_translation
        full[~(reachable[:, None] & reachable[None, :])] = -np.inf
        neighbours = np.max(
            [np.roll(full, (a, b), axis=(0, 1)) for a in (-1, 0, 1) for b in (-1, 0, 1)], axis=0
        )
        flat = np.flatnonzero((full == neighbours) & np.isfinite(full))
        best = flat[np.argsort(-full.ravel()[flat], kind='stable')[:5]]
        u, v = np.unravel_index(best, full.shape)
        expected.append(np.column_stack([np.full(5, yaw), shift[u], shift[v]]))
    np.testing.assert_array_equal(peaks[:, 1:], np.concatenate(expected))
    best = peaks[np.argmax(peaks[:, 0])]
    assert best[1] == 17.0 and abs(best[2] - 11.0) <= 1.0 and abs(best[3] + 6.0) <= 1.0


@pytest.mark.parametrize('seed', [0, 3])
def test_compiled_bev_channel_sums_are_the_numpy_sums(seed, monkeypatch):
    """The four quarter turns' channel sums: bit for bit the NumPy reference's."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(-20, 20, (2000, 2))
    channel = rng.integers(0, 3, 2000)
    grid = bev_search.BevGrid.make(1.0, 12.0, 10.0)
    correlator = bev_search.Correlator(points, channel, points, channel, grid, 3)
    source = correlator._source_window(points[None])
    source = np.concatenate([source, source[:, ::-1]])  # two grids
    spectrum = fft.fft(fft.rfft(source, n=grid.size, axis=-1), n=grid.size, axis=-2)
    slot = np.array([[0, 2, -1, 5], [-1, 1, 3, 4]])  # grid, quarter -> where its sum goes
    fast = correlator._turned_sums(spectrum, slot)
    monkeypatch.setenv(kernels.ENV_SWITCH, 'numpy')
    slow = correlator._turned_sums(spectrum, slot)
    assert fast.dtype == slow.dtype == np.complex64 and fast.shape == (
        6,
        grid.size,
        grid.size // 2 + 1,
    )
    np.testing.assert_array_equal(fast, slow)
    np.testing.assert_allclose(
        slow[0],
        (np.conj(spectrum[0]) * correlator.target_spectrum).sum(axis=0),
        rtol=1e-5,
        atol=1e-4,
    )


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), extent=st.sampled_from([5.0, 60.0, 5000.0]))
def test_the_compiled_compatibility_is_the_exact_length_consistency(seed, extent):
    """Every pair with c_ij clear of d by 1 mm is compatible as the exact rule says."""
    from mlsemreg_ros.core.estimation.sc2pcr import compatibility_matrix

    rng = np.random.default_rng(seed)
    src = rng.uniform(-extent, extent, (300, 3))
    truth = motion(30.0, (2.0, -1.0, 0.5))
    dst = apply_transform(truth, src)
    dst[150:] = rng.uniform(-extent, extent, (150, 3))  # outliers
    dst[:150] += rng.normal(0.0, 0.2, (150, 3))
    threshold = 0.6
    compiled = compatibility_matrix(src, dst, threshold, compiled=True).toarray()
    blocked = compatibility_matrix(src, dst, threshold, compiled=False).toarray()
    lengths = np.abs(
        np.linalg.norm(src[:, None] - src[None], axis=2)
        - np.linalg.norm(dst[:, None] - dst[None], axis=2)
    )
    clear = np.abs(lengths - threshold) > 1e-3
    exact = np.where(lengths < threshold, np.maximum(1.0 - (lengths / threshold) ** 2, 1e-12), 0)
    np.fill_diagonal(exact, 1.0)
    assert np.array_equal(compiled[clear] > 0, exact[clear] > 0)
    assert np.abs(compiled - exact)[clear].max() < 1e-3  # c_ij to float32 rounding
    assert np.array_equal(compiled, compiled.T)
    assert np.array_equal(compiled[clear] > 0, blocked[clear] > 0)


@pytest.mark.parametrize('seed', range(6))
def test_compiled_free_space_test_is_the_numpy_test(seed, monkeypatch):
    """The covisible overlap's seen-through points: the same with the kernel as with NumPy."""
    rng = np.random.default_rng(seed)
    scan = rng.normal(0.0, 15.0, (3000, 3)) * np.array([1.0, 1.0, 0.1])
    image = RangeImage.of(scan, 2.0)
    moved = rng.normal(0.0, 20.0, (5000, 3)) * np.array([1.0, 1.0, 0.15])
    moved[:10] = 0.0  # at the sensor
    on = rng.random(5000) < 0.3
    fast = image.seen_through(moved, on, 1.0)
    monkeypatch.setenv(kernels.ENV_SWITCH, 'numpy')
    slow = image.seen_through(moved, on, 1.0)
    np.testing.assert_array_equal(fast, slow)
    assert 0 < np.count_nonzero(fast) < np.count_nonzero(~on)  # some seen through, not all
    assert not fast[on].any()

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
"""The compiled kernels (core/features/kernels.py): switch, cache, voxel grid equal to NumPy's."""

import itertools
from pathlib import Path
import subprocess
import sys

from mlsemreg_ros.core.features import kernels
from mlsemreg_ros.core.features.features import voxel_centroids, voxel_downsample, voxel_groups
from mlsemreg_ros.core.features.warm_up import warm_up
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

needs_numba = pytest.mark.skipif(not kernels.AVAILABLE, reason='numba is not installed')


def test_environment_switch_disables_the_kernels(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(kernels.ENV_SWITCH, 'numpy')
    assert not kernels.enabled()
    assert kernels.use_compiled(None) is False
    assert warm_up() == {}
    monkeypatch.setenv(kernels.ENV_SWITCH, 'numba')
    assert kernels.enabled() == kernels.AVAILABLE
    assert kernels.use_compiled(False) is False


def test_cache_directory_falls_back_when_the_package_is_read_only(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.delenv('NUMBA_CACHE_DIR', raising=False)
    package = Path(kernels.__file__).resolve().parent
    real_access = kernels.os.access

    def access(path: object, mode: int) -> bool:
        return False if Path(str(path)).resolve() == package else real_access(path, mode)

    monkeypatch.setattr(kernels.os, 'access', access)
    monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path))
    chosen = kernels.cache_directory()
    assert chosen == str(tmp_path / 'mlsemreg_ros' / 'numba')
    assert Path(chosen).is_dir()
    blocked = tmp_path / 'a-file'
    blocked.write_text('')
    monkeypatch.setenv('XDG_CACHE_HOME', str(blocked))  # mkdir fails: the temp folder
    monkeypatch.setattr(kernels.tempfile, 'gettempdir', lambda: str(tmp_path / 'tmp'))
    assert Path(kernels.cache_directory()).parent == tmp_path / 'tmp'
    monkeypatch.setenv('NUMBA_CACHE_DIR', str(tmp_path / 'explicit'))
    assert kernels.cache_directory() == str(tmp_path / 'explicit')


@needs_numba
def test_warm_up_compiles_into_the_on_disk_cache() -> None:
    timings = warm_up()
    assert set(timings) == {
        'voxel_ms',
        'fpfh_ms',
        'deskew_ms',
        'sweep_ms',
        'labels_ms',
        'total_ms',
    }
    folder = Path(kernels.cache_directory() or Path(kernels.__file__).parents[1])  # core/
    names = ' '.join(p.name for p in folder.rglob('*.nbi'))
    for kernel in (
        '_voxel_slots',
        '_voxel_sums',
        '_majority',
        'pair_angles',
        'histograms',
        'covariances',
        'support_neighbour_sums',
        'keypoint_neighbour_sums',
        '_deskew_piecewise',
        'fit_bins',
        'cell_features',
        'column_extent',
        'support_counts',
        'window_sum',
    ):
        assert kernel in names


def _scan_like(seed: int, n: int) -> np.ndarray:
    """Points along rings around a sensor (scan order), with a few far outliers."""
    rng = np.random.default_rng(seed)
    angle = np.sort(rng.uniform(-np.pi, np.pi, n))
    ring = rng.integers(0, 16, n)
    distance = 3.0 + 2.0 * ring + rng.normal(0, 0.05, n)
    points = np.c_[distance * np.cos(angle), distance * np.sin(angle), -1.7 + 0.1 * ring]
    points[rng.integers(0, n, 5)] += rng.normal(0, 80.0, (5, 3))
    return points


@needs_numba
@pytest.mark.parametrize('seed', [0, 1, 2, 3])
def test_compiled_voxels_equal_numpy_bit_for_bit(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 6000))
    points = _scan_like(seed, n) if seed % 2 else rng.uniform(-30, 30, (n, 3))
    labels = rng.integers(0, [3, 20, 300, 5000][seed], n)  # dense table / pair counting
    size = float(rng.choice([0.05, 0.3, 1.0]))
    for function in (voxel_groups, voxel_centroids):
        ours = function(points, size, compiled=True)
        reference = function(points, size, compiled=False)
        for got, want in zip(ours, reference, strict=True):
            np.testing.assert_array_equal(got, want)
    (c_pts, c_lab), (n_pts, n_lab) = (
        voxel_downsample(points, labels, size, compiled=flag) for flag in (True, False)
    )
    np.testing.assert_array_equal(c_pts, n_pts)  # same voxels, same order, same rounding
    np.testing.assert_array_equal(c_lab, n_lab)
    assert c_lab.dtype == n_lab.dtype == np.int32


@needs_numba
def test_every_point_in_its_own_voxel_grows_the_hash_table() -> None:
    points = np.random.default_rng(4).uniform(-100, 100, (5000, 3))  # V = N: one retry
    inverse, sums, sizes = kernels.voxel_grid(points, 1e-3)
    order = np.lexsort(np.floor(points / 1e-3).T[::-1])
    np.testing.assert_array_equal(inverse[order], np.arange(5000))
    np.testing.assert_array_equal(sums[inverse], points)
    assert np.all(sizes == 1)


@needs_numba
def test_overflowing_key_extent_falls_back_to_numpy() -> None:
    points = np.array([[0.0, 0.0, 0.0], [1e12, 1e12, 1e12], [0.1, 0.0, 0.0]])
    assert kernels.voxel_grid(points, 1e-3) is None
    centroids, labels = voxel_downsample(points, np.array([1, 2, 3]), 1e-3, compiled=True)
    np.testing.assert_array_equal(centroids, points[[0, 2, 1]])
    np.testing.assert_array_equal(labels, [1, 3, 2])


@needs_numba
def test_compiled_majority_known_answers() -> None:
    # Voxel (0,0,0): 5, 7, 7 -> 7; voxel (1,0,0): a 3-vs-9 tie -> 3; (-1,0,0) alone -> 2.
    points = np.array(
        [
            [0.1, 0.1, 0.1],
            [0.2, 0.2, 0.2],
            [0.3, 0.3, 0.3],
            [1.2, 0.1, 0.1],
            [1.4, 0.3, 0.1],
            [-0.5, 0.5, 0.5],
        ]
    )
    labels = np.array([5, 7, 7, 9, 3, 2], dtype=np.int32)
    centroids, voxel_labels = voxel_downsample(points, labels, 1.0, compiled=True)
    np.testing.assert_allclose(centroids, [[-0.5, 0.5, 0.5], [0.2, 0.2, 0.2], [1.3, 0.2, 0.1]])
    np.testing.assert_array_equal(voxel_labels, [2, 7, 3])
    winner = kernels.majority(np.array([0, 0, 1, 1, 1]), np.array([2, 1, 0, 2, 2]), 2, 3)
    np.testing.assert_array_equal(winner, [1, 2])  # tie 1-vs-2 -> index 1


@needs_numba
def test_empty_and_single_point_clouds() -> None:
    inverse, sums, sizes = kernels.voxel_grid(np.zeros((0, 3)), 0.5)
    assert inverse.shape == (0,) and sums.shape == (0, 3) and sizes.shape == (0,)
    centroids, labels = voxel_downsample(
        np.array([[1.0, 2.0, 3.0]]), np.array([4]), 0.5, compiled=True
    )
    np.testing.assert_array_equal(centroids, [[1.0, 2.0, 3.0]])
    np.testing.assert_array_equal(labels, [4])


def test_keep_freed_memory_removes_the_page_faults_of_repeated_allocations() -> None:
    # 40 MB arrays are above glibc's largest dynamic mmap threshold (32 MB): by default
    # each one is fresh mmap pages (a fault per 4 KiB page), once kept they are reused.
    script = (
        'import resource, sys, numpy as np\n'
        'from mlsemreg_ros.core.features import kernels\n'
        'if sys.argv[1] == "1": assert kernels.keep_freed_memory(64 << 20, 512 << 20)\n'
        'for _ in range(3): np.ones(5 << 20).sum()\n'
        'start = resource.getrusage(resource.RUSAGE_SELF).ru_minflt\n'
        'for _ in range(10): np.ones(5 << 20).sum()\n'
        'print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - start)\n'
    )
    faults = [
        int(
            subprocess.run(
                [sys.executable, '-c', script, flag], check=True, capture_output=True, text=True
            ).stdout
        )
        for flag in ('0', '1')
    ]
    assert faults[0] > 1000, faults  # at least some fresh pages per array (huge pages: fewer)
    assert faults[1] < faults[0] / 10, faults


@needs_numba
@pytest.mark.parametrize(
    'omega',
    [np.array([0.1, -0.4, 1.2]), np.zeros(3), np.array([0.0, 0.0, 1e-9])],
    ids=['turning', 'straight', 'series'],
)
def test_compiled_deskew_equals_numpy(omega: np.ndarray, monkeypatch: pytest.MonkeyPatch) -> None:
    """The one-pass deskew kernel gives NumPy's points (to the last bits of a dot product)."""
    from mlsemreg_ros.core.features import deskew

    rng = np.random.default_rng(4)
    points = _scan_like(4, 5000)
    times = np.repeat(np.sort(rng.uniform(-0.01, 0.1, 500)), 10)  # columns: times repeat
    times[rng.integers(0, 5000, 20)] = 0.0
    motion = deskew.SweepMotion(omega, np.array([9.0, -1.0, 0.3]))
    monkeypatch.setenv(kernels.ENV_SWITCH, 'numpy')
    expected = deskew.deskew(points, times, motion)
    monkeypatch.setenv(kernels.ENV_SWITCH, 'numba')
    compiled = deskew.deskew(points, times, motion)
    np.testing.assert_allclose(compiled, expected, rtol=0.0, atol=1e-12)
    assert np.mean(compiled == expected) > 0.99
    assert not np.array_equal(expected, points)  # it did move them


@needs_numba
def test_compiled_piecewise_deskew_equals_numpy_and_the_per_segment_maps(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """One pass over all segments = NumPy's one pass = each segment mapped on its own."""
    from mlsemreg_ros.core.features import deskew

    rng = np.random.default_rng(5)
    points = _scan_like(5, 6000)
    times = np.repeat(np.sort(rng.uniform(-0.02, 0.12, 600)), 10)  # beyond both end nodes
    nodes = np.array([-0.01, 0.0, 0.02, 0.05, 0.08, 0.1])
    rates = np.array([[0.1, -0.4, 1.2], [0.0, 0.0, 0.0], [0.0, 0.0, 1e-12], [0.3, 0.1, -0.8]])
    steps = [
        Rotation.from_rotvec(w * d).as_matrix()
        for w, d in zip(rates, np.diff(nodes[1:]), strict=True)
    ]
    rotations = np.stack([np.eye(3), np.eye(3), *itertools.accumulate(steps, np.matmul)])
    motion = deskew.PiecewiseSweepMotion.from_rotations(
        nodes, rotations, np.array([9.0, 1.0, 0.2])
    )
    monkeypatch.setenv(kernels.ENV_SWITCH, 'numpy')
    expected = deskew.deskew(points, times, motion)
    monkeypatch.setenv(kernels.ENV_SWITCH, 'numba')
    compiled = deskew.deskew(points, times, motion)
    np.testing.assert_allclose(compiled, expected, rtol=0.0, atol=1e-12)
    segments = motion.segments()
    index = np.clip(np.searchsorted(nodes, times, side='right') - 1, 0, len(segments) - 1)
    separately = np.empty_like(points)
    for k, (start, pose, twist) in enumerate(segments):
        rows = index == k
        local = deskew.deskew(points[rows], times[rows] - start, twist)
        separately[rows] = local @ pose[:3, :3].T + pose[:3, 3]
    np.testing.assert_allclose(compiled, separately, rtol=0.0, atol=1e-12)
    assert np.mean(compiled == separately) > 0.5  # the pose product may round differently
    assert not np.array_equal(expected, points)
    order = rng.permutation(len(points))  # any order: the runs of equal times break up
    for switch in ('numpy', 'numba'):
        monkeypatch.setenv(kernels.ENV_SWITCH, switch)
        shuffled = deskew.deskew(points[order], times[order], motion)
        np.testing.assert_allclose(shuffled, separately[order], rtol=0.0, atol=1e-12)

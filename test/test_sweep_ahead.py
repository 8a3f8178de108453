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
The sweep alignment started ahead on a second thread (``core/odometry/sweep_ahead.py``).

Its result is used only for the very inputs it was started with, and the odometry's poses
and covariances are those of the serial path, bit for bit, on a simulated solid-state drive.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from mlsemreg_ros.core import threads
from mlsemreg_ros.core.alignment.config import SweepAlignmentConfig
from mlsemreg_ros.core.features.deskew import SweepMotion
from mlsemreg_ros.core.odometry import sweep_ahead
from mlsemreg_ros.core.odometry.sweep_ahead import fingerprint, Memo, SweepAhead, SweepInputs
import numpy as np
import pytest


@pytest.fixture
def two_workers():
    before = threads.workers()
    threads.configure(2)
    yield
    threads.configure(before)


def _twist(rate: float) -> SweepMotion:
    return SweepMotion(np.array([0.0, 0.0, rate]), np.array([5.0, 0.0, 0.0]))


def test_the_result_is_taken_only_for_the_inputs_it_was_started_with(two_workers) -> None:
    raw, gaussians, config = SimpleNamespace(), object(), SweepAlignmentConfig()
    pose = np.eye(4)
    pose[0, 3] = 0.1
    ahead = SweepAhead()
    started = []

    def ahead_of(T: np.ndarray) -> str:
        return 'ahead'

    assert ahead.start(SweepInputs(raw, gaussians, pose, _twist(0.1), config), started.append)
    assert ahead.started_for(raw) and not ahead.started_for(SimpleNamespace())
    # the pose is copied when started: a later change of the caller's array is no match
    same = pose.copy()
    pose[0, 3] = 0.2
    assert ahead.take(SweepInputs(raw, gaussians, same, _twist(0.1), config)) is None  # None
    assert np.array_equal(started[0], same)
    assert not ahead.started_for(raw)  # taken once
    for other in (
        (SimpleNamespace(), gaussians, same, _twist(0.1), config),  # another scan object
        (raw, object(), same, _twist(0.1), config),  # other Gaussians
        (raw, gaussians, same + 1e-12, _twist(0.1), config),  # another pose, by one bit
        (raw, gaussians, same, _twist(0.1 + 1e-15), config),  # another implied twist
        (raw, gaussians, same, None, config),
        (raw, gaussians, same, _twist(0.1), SweepAlignmentConfig(points=500)),
    ):
        assert ahead.start(SweepInputs(raw, gaussians, same, _twist(0.1), config), ahead_of)
        assert ahead.take(SweepInputs(*other)) is None
    assert ahead.start(SweepInputs(raw, gaussians, same, _twist(0.1), config), ahead_of)
    assert ahead.take(SweepInputs(raw, gaussians, same.copy(), _twist(0.1), config)) == 'ahead'
    assert ahead.take(SweepInputs(raw, gaussians, same, _twist(0.1), config)) is None  # taken


def test_a_failed_start_is_computed_again_by_the_caller(two_workers) -> None:
    def fails(T: np.ndarray) -> None:
        raise FloatingPointError('diverged')

    ahead, raw, gaussians, config = SweepAhead(), object(), object(), SweepAlignmentConfig()
    assert ahead.start(SweepInputs(raw, gaussians, np.eye(4), None, config), fails)
    assert ahead.take(SweepInputs(raw, gaussians, np.eye(4), None, config)) is None


def test_one_worker_starts_nothing() -> None:
    before = threads.workers()
    threads.configure(1)
    try:
        ahead = SweepAhead()
        inputs = SweepInputs(object(), object(), np.eye(4), None, SweepAlignmentConfig())
        assert not ahead.start(inputs, id)
        assert not ahead.started_for(None)
    finally:
        threads.configure(before)


def test_the_memo_returns_its_result_only_for_the_same_bits() -> None:
    calls = []

    def function(a: np.ndarray, config: object, scale: float = 1.0) -> float:
        calls.append(1)
        return float(np.sum(a)) * scale

    config = object()
    a = np.array([1.0, 2.0])
    memo = Memo(function, (a, config), {'scale': 2.0})
    assert memo((a.copy(), config), {'scale': 2.0}) == 6.0 and len(calls) == 1  # kept
    assert memo((a, object()), {'scale': 2.0}) == 6.0 and len(calls) == 2  # another config
    assert memo((a, config), {'scale': 3.0}) == 9.0 and len(calls) == 3
    failed = Memo(lambda x: 1.0 / x, (0,), {})  # raises when called early: kept for later
    with pytest.raises(ZeroDivisionError):
        failed((0,), {})
    assert failed((2,), {}) == 0.5
    assert fingerprint(0.0) != fingerprint(-0.0)  # equal floats, other bits
    assert fingerprint(np.array([np.nan])) == fingerprint(np.array([np.nan]))
    assert fingerprint(np.zeros(2)) != fingerprint(np.zeros((2, 1)))


@pytest.mark.slow
def test_the_odometry_s_poses_are_the_serial_path_s(tmp_path: Path, monkeypatch) -> None:
    """A simulated solid-state drive: the same poses and covariances, started ahead or not."""
    from mlsemreg_ros.core.config import load_settings, RegistrationConfig
    from mlsemreg_ros.core.odometry import Odometry
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.datasets.factory import open_scan_source
    from mlsemreg_ros.tools import simulate

    drive = tmp_path / 'livox'
    arguments = [str(drive), '--realism', 'field', '--frames', '14', '--seed', '5']
    assert simulate.main([*arguments, '--sensor', 'livox', '--quiet']) == 0
    source = open_scan_source(str(drive))
    try:
        scans = list(source.scans(1, None))
    finally:
        source.close()

    def run() -> np.ndarray:
        (core,) = load_settings((RegistrationConfig,), None, ['threads=2'])
        odometry = Odometry(Registration(core))
        rows = []
        for scan in scans:
            step = odometry.process(
                scan.xyz, scan.labels, scan.stamp_ns, point_times=scan.point_times
            )
            frame = step.frame_covariance if step.frame_covariance is not None else np.zeros(36)
            rows.append(np.concatenate([np.ravel(step.pose), np.ravel(frame)]))
        return np.array(rows)

    taken = []
    original = SweepAhead.take
    monkeypatch.setattr(
        SweepAhead, 'take', lambda self, *a: taken.append(original(self, *a)) or taken[-1]
    )
    ahead = run()
    assert sum(result is not None for result in taken) >= 5  # most tracked scans
    monkeypatch.setattr(sweep_ahead.SweepAhead, 'start', lambda self, *a: False)
    serial = run()
    assert ahead.tobytes() == serial.tobytes()

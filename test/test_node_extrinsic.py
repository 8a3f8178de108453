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
The sensor extrinsic: the math of ``ros/extrinsic.py``, and mlsemreg_node publishing the base.

The node test runs the real rclpy node (as test/test_node.py does) with ``base_frame``,
``T_base_sensor.*``, ``extrinsic_source: tf`` (tf2_ros is not installed here, so the
parameters hold, with a warning) and an IMU topic the probe publishes on.
"""

from __future__ import annotations

import itertools
from typing import Any

from mlsemreg_ros.core.config import ConfigError
from mlsemreg_ros.core.rigid import invert_transform
from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair
from mlsemreg_ros.ros.extrinsic import adjoint, ExtrinsicConfig, to_base
from mlsemreg_ros.ros.node_config import NodeConfig
from mlsemreg_ros.ros.probe import node_and_probe, NodeProbe, to_stamp
import numpy as np
from pose_messages import matrix
import pytest
from ros_domains import domain_id
from scipy.linalg import expm

DOMAIN_ID = domain_id('node_extrinsic')
TIMEOUT_S = 60.0
EXTRINSIC = {'x': 1.2, 'y': -0.3, 'z': 1.73, 'roll': 0.02, 'pitch': -0.05, 'yaw': 0.4}
_stamps = itertools.count(100)


def _twist_matrix(xi: np.ndarray) -> np.ndarray:
    v, w = xi[:3], xi[3:]
    out = np.zeros((4, 4))
    out[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
    out[:3, 3] = v
    return out


def test_the_extrinsic_matrix_follows_rep_103() -> None:
    X = ExtrinsicConfig(x=1.0, y=2.0, z=3.0, yaw=np.pi / 2).matrix()
    np.testing.assert_allclose(X[:3, 3], [1, 2, 3])
    np.testing.assert_allclose(X[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)  # yaw about z
    assert ExtrinsicConfig().is_identity()


def test_the_base_pose_and_twist_are_the_sensor_ones_moved_by_the_extrinsic() -> None:
    X = ExtrinsicConfig(**EXTRINSIC).matrix()
    xi = np.array([8.0, 0.3, -0.1, 0.01, -0.02, 0.5])  # sensor body twist [v, w]
    dt = 1e-6
    T_sensor = expm(_twist_matrix(xi))  # the sensor after 1 s
    cov = np.diag([1e-4, 2e-4, 3e-4, 1e-6, 2e-6, 3e-6])
    base = to_base(X, T_sensor, cov, xi, cov)
    np.testing.assert_allclose(base.pose, X @ T_sensor @ invert_transform(X), atol=1e-12)
    # the base's body twist: the finite difference of its pose
    step = X @ expm(_twist_matrix(xi) * dt) @ invert_transform(X)
    np.testing.assert_allclose(base.twist, _vee(step) / dt, rtol=1e-5, atol=1e-5)
    A = adjoint(X)
    np.testing.assert_allclose(base.covariance, A @ cov @ A.T)
    identity = to_base(np.eye(4), T_sensor, cov, xi, cov)
    np.testing.assert_allclose(identity.pose, T_sensor)
    np.testing.assert_allclose(identity.twist, xi)


def _vee(T: np.ndarray) -> np.ndarray:
    from scipy.linalg import logm

    log = np.real(logm(T))
    return np.array([log[0, 3], log[1, 3], log[2, 3], log[2, 1], log[0, 2], log[1, 0]])


def test_an_extrinsic_without_a_base_frame_is_refused() -> None:
    with pytest.raises(ConfigError, match='base_frame is empty'):
        NodeConfig().replace({'T_base_sensor.x': 1.0})
    with pytest.raises(ConfigError, match='tf needs a base_frame'):
        NodeConfig().replace({'extrinsic_source': 'tf'})
    with pytest.raises(ConfigError):
        NodeConfig().replace({'base_frame': 'base_link', 'T_base_sensor.yaw': 7.0})
    NodeConfig().replace({'base_frame': 'base_link', 'T_base_sensor.z': 1.73})


@pytest.fixture(scope='module')
def ros(rclpy_module: Any) -> Any:
    args = ['--ros-args', '-p', 'keypoints.count:=1500', '-p', 'base_frame:=base_link']
    args += ['-p', 'path.publish_period:=0.0']  # every scan's path (no 1 s throttle)
    args += ['-p', 'extrinsic_source:=tf', '-p', 'imu_topic:=imu/data']
    for key, value in EXTRINSIC.items():
        args += ['-p', f'T_base_sensor.{key}:={value}']
    with node_and_probe(DOMAIN_ID, args) as (node, probe):
        yield node, probe


def _send(probe: NodeProbe, points: np.ndarray, labels: np.ndarray) -> tuple[Any, dict]:
    stamp = to_stamp(next(_stamps) * 0.1)
    probe.publish(probe.cloud(points, np.asarray(labels).astype(np.uint32), stamp))
    status = probe.status_for(stamp, TIMEOUT_S)
    assert status is not None, 'no diagnostics for the scan'
    return stamp, status


def test_t_base_sensor_moves_the_published_pose_by_exactly_the_extrinsic(ros: Any) -> None:
    node, probe = ros
    from sensor_msgs.msg import Imu

    imu = probe.node.create_publisher(Imu, 'imu/data', 10)
    pair = synthetic_pair(seed=0)
    assert probe.reset()
    first_stamp, status = _send(probe, pair.pts_dst, pair.label_dst)
    assert status['level'] == 0, status['message']
    for k in range(5):  # a few IMU messages before the next scan
        msg = Imu()
        msg.header.stamp = to_stamp(next(_stamps) * 0.1 - 0.05 + 0.01 * k)
        msg.header.frame_id = 'velodyne'
        msg.linear_acceleration.z = 9.81
        imu.publish(msg)
    assert probe.wait_until(lambda: node._prior.counts['imu'] == 5, 10.0)
    stamp, status = _send(probe, pair.pts_src, pair.label_src)
    assert status['level'] == 0, status['message']
    transform = probe.wait_for('transform', stamp, 5.0)  # T_keyframe_current: the sensor's
    first = probe.wait_for('odometry', first_stamp, 5.0)
    odom = probe.wait_for('odometry', stamp, 5.0)
    assert (odom.header.frame_id, odom.child_frame_id) == ('odom', 'base_link')
    np.testing.assert_allclose(matrix(first.pose.pose), np.eye(4), atol=1e-9)
    X = ExtrinsicConfig(**EXTRINSIC).matrix()
    T_sensor = matrix(transform.transform)
    expected = X @ T_sensor @ invert_transform(X)
    np.testing.assert_allclose(matrix(odom.pose.pose), expected, atol=1e-6)
    assert not np.allclose(expected, T_sensor, atol=1e-3)  # the extrinsic does move it
    path = probe.wait_for('path', stamp, 5.0)
    np.testing.assert_allclose(matrix(path.poses[-1].pose), expected, atol=1e-6)
    # the IMU reached the motion model (tf2_ros missing: the parameters were used)
    assert len(node._odometry.motion_model._imu) == 5


class _Model:
    def __init__(self) -> None:
        self.imu: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.wheel: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def add_imu(self, stamps: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> None:
        self.imu.append((stamps, gyro, accel))

    def add_wheel(self, stamps: np.ndarray, poses: np.ndarray, extrinsic: np.ndarray) -> None:
        self.wheel.append((stamps, poses, extrinsic))


def _header(seconds: int, frame: str) -> Any:
    from types import SimpleNamespace

    return SimpleNamespace(stamp=SimpleNamespace(sec=seconds, nanosec=0), frame_id=frame)


def _vector(x: float, y: float, z: float) -> Any:
    from types import SimpleNamespace

    return SimpleNamespace(x=x, y=y, z=z)


def test_prior_messages_in_the_base_frame_are_moved_to_the_sensor() -> None:
    from types import SimpleNamespace

    from mlsemreg_ros.ros.prior_inputs import PriorInbox

    X = ExtrinsicConfig(yaw=np.pi / 2, x=1.0).matrix()  # sensor x = base y
    inbox, model = PriorInbox(), _Model()
    imu = SimpleNamespace(
        header=_header(1, 'base_link'),
        angular_velocity=_vector(0.0, 0.0, 0.5),
        linear_acceleration=_vector(0.0, 2.0, 9.81),  # forward in base y: the sensor's x
    )
    pose = SimpleNamespace(
        position=_vector(3.0, 0.0, 0.0), orientation=SimpleNamespace(x=0, y=0, z=0, w=1)
    )
    wheel = SimpleNamespace(
        header=_header(1, 'odom'), child_frame_id='base_link', pose=SimpleNamespace(pose=pose)
    )
    inbox.on_imu(imu)
    inbox.on_wheel(wheel)
    inbox.flush(model, 'velodyne', 'base_link', X)
    stamps, gyro, accel = model.imu[0]
    assert stamps.tolist() == [1_000_000_000]
    np.testing.assert_allclose(accel[0], [2.0, 0.0, 9.81], atol=1e-12)
    np.testing.assert_allclose(gyro[0], [0.0, 0.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(model.wheel[0][2], X)
    np.testing.assert_allclose(model.wheel[0][1][0][:3, 3], [3.0, 0.0, 0.0])
    inbox.on_imu(imu)
    inbox.flush(object(), 'velodyne', 'base_link', X)  # a model that takes none: dropped
    inbox.flush(model, 'velodyne', 'base_link', X)
    assert len(model.imu) == 1
    imu.header = _header(2, 'imu_link')  # neither frame: used as it is, with one warning
    inbox.on_imu(imu)
    imu.header = _header(3, 'imu_link')  # (a repeated stamp would be dropped)
    inbox.on_imu(imu)
    inbox.flush(model, 'velodyne', 'base_link', X)
    assert len(inbox.warnings) == 1 and 'imu_link' in inbox.warnings[0]
    np.testing.assert_allclose(model.imu[-1][2][0], [0.0, 2.0, 9.81])

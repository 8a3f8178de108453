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
mlsemreg_node with the real rclpy: topics, frames, stamps, parameters, bad input, reset.

The node and a probe node run in a private rclpy context (a ROS_DOMAIN_ID of
their own, see ros_domains.py) with an executor thread; the probe publishes
scans on ``points`` and waits for the node's ``/diagnostics`` entry of each scan
(stamp-matched) before looking at the outputs. The accuracy test runs with the
default parameters; the tests of ROS behaviour start the node with
``keypoints.count:=1500`` (SC2-PCR's cost grows with the square of the
correspondences) to keep the module fast.
"""

from __future__ import annotations

import dataclasses
import itertools
from typing import Any

from mlsemreg_ros.codec.pointcloud2 import FLOAT64
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.metrics import rotation_error_deg, translation_error_m
from mlsemreg_ros.datasets.pairs import dev_pairs_dir, list_pairs, load_pair
from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair
from mlsemreg_ros.ros.probe import node_and_probe, NodeProbe, to_stamp
import numpy as np
from pose_messages import matrix
import pytest
from ros_domains import domain_id

pytestmark = pytest.mark.usefixtures('rclpy_module')  # skip without rclpy (conftest.py)

DOMAIN_ID = domain_id('node')
TIMEOUT_S = 60.0
KEYPOINTS = 1500  # keypoints.count of the behaviour tests
_stamps = itertools.count(100)


def _next_stamp() -> Any:
    return to_stamp(next(_stamps) * 0.1)


@pytest.fixture(scope='module')
def ros() -> Any:
    args = [
        '--ros-args',
        '-p',
        f'keypoints.count:={KEYPOINTS}',
        '-p',
        'path.publish_period:=0.0',
    ]  # every path, for the checks
    with node_and_probe(DOMAIN_ID, args) as (node, probe):
        yield node, probe


@pytest.fixture(scope='module')
def scene() -> Any:
    """Return the synthetic street pair (fast; used by every test but the accuracy one)."""
    return synthetic_pair(seed=0)


@pytest.fixture
def probe(ros: Any) -> NodeProbe:
    """Return the probe after a reset of the node (fresh odometry, no keyframe)."""
    _, probe = ros
    assert probe.reset()
    return probe


def send(probe: NodeProbe, points: np.ndarray, labels: np.ndarray, **kw: Any) -> tuple[Any, dict]:
    """Publish one scan; return its stamp and the node's diagnostics for it."""
    stamp = _next_stamp()
    probe.publish(probe.cloud(points, np.asarray(labels).astype(np.uint32), stamp, **kw))
    status = probe.status_for(stamp, TIMEOUT_S)
    assert status is not None, 'no diagnostics for the scan'
    return stamp, status


def send_pair(probe: NodeProbe, pair: Any) -> tuple[Any, Any, dict]:
    """Send dst (becomes the keyframe), then src; return both stamps and src's status."""
    dst_stamp, status = send(probe, pair.pts_dst, pair.label_dst)
    assert status['level'] == 0, status['message']
    src_stamp, status = send(probe, pair.pts_src, pair.label_src)
    return dst_stamp, src_stamp, status


def assert_close_to(estimate: np.ndarray, truth: np.ndarray) -> None:
    re = rotation_error_deg(estimate[:3, :3], truth[:3, :3])
    te = translation_error_m(estimate[:3, 3], truth[:3, 3])
    assert re <= 5.0 and te <= 0.6, f'RE {re:.2f} deg, TE {te:.3f} m'


@pytest.fixture
def defaults(probe: NodeProbe) -> NodeProbe:
    """Return the probe with the node at its default keypoints.count (restored afterwards)."""
    default = RegistrationConfig().keypoints.count
    assert all(r.successful for r in probe.set_parameters({'keypoints.count': default}))
    yield probe
    probe.reset()  # no keyframe to re-prepare when the count goes back
    assert all(r.successful for r in probe.set_parameters({'keypoints.count': KEYPOINTS}))


def test_registers_a_pair_with_the_right_frames_and_stamps(defaults: NodeProbe) -> None:
    probe = defaults
    directory = dev_pairs_dir()
    if directory.is_dir() and list_pairs(directory):
        pair = load_pair(list_pairs(directory)[0])
    else:  # no dev pairs: the synthetic street
        pair = synthetic_pair(seed=1)
    dst_stamp, src_stamp, status = send_pair(probe, pair)
    assert status['level'] == 0, status['message']
    msg = probe.wait_for('transform', src_stamp, 5.0)
    assert msg is not None, 'no mlsemreg/transform for the current scan'
    assert (msg.header.frame_id, msg.child_frame_id) == ('velodyne', 'velodyne')
    assert_close_to(matrix(msg.transform), pair.trans_gt)
    assert float(status['latency_ms']) > 0
    assert status['keyframe_stamp'] == f'{dst_stamp.sec + 1e-9 * dst_stamp.nanosec:.9f}'
    # Odometry: identity for the keyframe, then keyframe pose @ T.
    first = probe.wait_for('odometry', dst_stamp, 5.0)
    odom = probe.wait_for('odometry', src_stamp, 5.0)
    for m in (first, odom):
        assert (m.header.frame_id, m.child_frame_id) == ('odom', 'velodyne')
    np.testing.assert_allclose(matrix(first.pose.pose), np.eye(4), atol=1e-9)
    np.testing.assert_allclose(matrix(odom.pose.pose), matrix(msg.transform), atol=1e-6)
    cov = np.asarray(odom.pose.covariance).reshape(6, 6)
    assert np.all(np.diag(cov) > 0) and np.all(np.diag(cov) < 1.0)
    np.testing.assert_allclose(cov, cov.T)  # the fine alignment's full covariance
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    twist = odom.twist.twist.linear  # 0.1 s between the stamps
    np.testing.assert_allclose(
        [twist.x, twist.y, twist.z], matrix(msg.transform)[:3, 3] / 0.1, rtol=1e-6, atol=1e-6
    )
    path = probe.wait_for('path', src_stamp, 5.0)
    assert path.header.frame_id == 'odom' and len(path.poses) == 2
    assert [p.header.frame_id for p in path.poses] == ['odom', 'odom']
    assert path.poses[-1].header.stamp == src_stamp
    markers = probe.markers_for(src_stamp, 5.0)
    assert markers is not None, 'no mlsemreg/correspondences for the current scan'
    by_ns = {m.ns: m for m in markers.markers[1:]}
    assert markers.markers[0].action == markers.markers[0].DELETEALL
    assert 'inliers' in by_ns and 'outliers' not in by_ns
    assert all(m.header.frame_id == 'velodyne' for m in markers.markers)
    assert len(by_ns['inliers'].points) % 2 == 0 and len(by_ns['inliers'].points) > 0
    if 'landmarks' in by_ns:
        assert len(by_ns['landmarks'].colors) == len(by_ns['landmarks'].points)


def test_parameter_change_applies_from_the_next_frame(probe: NodeProbe, scene: Any) -> None:
    send_pair(probe, scene)
    # 300 keypoints give fewer inliers: the sparse threshold goes down with them
    results = probe.set_parameters(
        {'keypoints.count': 300, 'publish_outliers': True, 'estimator.min_inliers': 10}
    )
    assert all(r.successful for r in results), [r.reason for r in results]
    try:
        assert probe.get_parameters(['keypoints.count']) == [300]
        stamp, status = send(probe, scene.pts_dst, scene.label_dst)
        assert status['level'] == 0, status['message']
        assert int(status['source_keypoints']) <= 300
        assert int(status['target_keypoints']) <= 300  # the keyframe was re-prepared
        markers = probe.markers_for(stamp, 5.0)
        assert 'outliers' in {m.ns for m in markers.markers}
    finally:
        probe.reset()
        results = probe.set_parameters(
            {
                'keypoints.count': KEYPOINTS,
                'publish_outliers': False,
                'estimator.min_inliers': RegistrationConfig().estimator.min_inliers,
            }
        )
        assert all(r.successful for r in results)


@pytest.mark.parametrize(
    ('name', 'value', 'reason'),
    [
        ('semantic.local_radius', 50.0, 'out of range'),
        ('keypoints.count', 5, 'out of range'),
        ('estimator.k2', 40, 'estimator.k2=40 must not exceed estimator.k1=30'),
        ('semantic.ring_count', 256, 'receptive-field limit'),
        ('bev_search.max_translation', 450.0, 'memory grows with its square'),
        ('bev_search.classes', ['castle'], "unknown class 'castle'"),
        ('semantic.landmark_classes', ['pole', 'lamppost'], "unknown class 'lamppost'"),
        ('semantic.ignored_classes', ['pole'], 'both landmark and ignored'),
        ('keyframe.policy', 'sometimes', "is not one of ['every_frame', 'distance']"),
        ('semantic.label_scheme', 'binary', 'is not one of'),
        ('odom_frame', '/odom', 'must not start with'),
        ('qos.depth', 3, 'read-only'),
        ('keypoints.count', 'many', 'Wrong parameter type'),
    ],
)
def test_invalid_parameter_changes_are_rejected(
    ros: Any, name: str, value: Any, reason: str
) -> None:
    node, probe = ros
    before = probe.get_parameters([name])
    core_before = node._params.snapshot()
    (result,) = probe.set_parameters({name: value})
    assert not result.successful
    assert reason in result.reason
    assert probe.get_parameters([name]) == before
    assert node._params.snapshot() == core_before


def test_a_rejected_change_leaves_the_process_thread_count(ros: Any) -> None:
    """Checking a change must not apply any of it: threads with an unknown class is refused."""
    from mlsemreg_ros.core import threads
    from rclpy.parameter import Parameter

    node, _ = ros
    before = threads.workers()
    change = [
        Parameter('threads', value=before + 1),
        Parameter('semantic.landmark_classes', value=['pole', 'lamppost']),
    ]
    result = node._params._validate(change)
    assert not result.successful and "unknown class 'lamppost'" in result.reason
    assert threads.workers() == before


def test_malformed_input_is_skipped_and_the_node_keeps_working(
    probe: NodeProbe, scene: Any
) -> None:
    good = probe.cloud(scene.pts_dst, scene.label_dst.astype(np.uint32), _next_stamp())

    def variant(**changes: Any) -> Any:
        msg = type(good)(
            header=good.header,
            height=good.height,
            width=good.width,
            fields=list(good.fields),
            is_bigendian=good.is_bigendian,
            point_step=good.point_step,
            row_step=good.row_step,
            data=good.data,
            is_dense=good.is_dense,
        )
        for key, value in changes.items():
            setattr(msg, key, value)
        return msg

    def field(which: str, **changes: Any) -> list:
        out = []
        for f in good.fields:
            f = type(f)(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count)
            if f.name == which:
                for key, value in changes.items():
                    setattr(f, key, value)
            out.append(f)
        return out

    nan_points = np.full_like(scene.pts_dst[:100], np.nan)
    cases = {
        'missing coordinate field': variant(fields=field('x', name='intensity')),
        'missing label field': variant(fields=field('label', name='class')),
        'unsupported datatype': variant(fields=field('label', datatype=9)),
        'data has': variant(data=bytes(good.data)[:-5]),
        'row_step': variant(point_step=good.point_step + 4),
        'big-endian': variant(is_bigendian=True),
        'NaN/inf coordinates': probe.cloud(nan_points, np.ones(100, np.uint32), _next_stamp()),
        'zero points': variant(width=0, row_step=0, data=b''),
        'non-integral float': probe.cloud(
            scene.pts_dst[:100], np.full(100, 1.5), _next_stamp(), label_datatype='float32'
        ),
        'unusable labels': probe.cloud(
            scene.pts_dst[:100], np.full(100, 70), _next_stamp(), label_datatype='uint32'
        ),
    }
    # 'unusable labels': raw ids are fine in auto mode, so force the learning scheme.
    # ('missing label field': only label_source field requires one; auto labels by geometry)
    assert all(
        r.successful
        for r in probe.set_parameters(
            {'semantic.label_scheme': 'learning', 'label_source': 'field'}
        )
    )
    try:
        for reason, msg in cases.items():
            msg.header.stamp = _next_stamp()
            probe.publish(msg)
            status = probe.status_for(msg.header.stamp, TIMEOUT_S)
            assert status is not None, f'{reason}: no diagnostics'
            assert status['level'] == 1, f'{reason}: {status["message"]}'
            expected = 'learning ids must lie' if reason == 'unusable labels' else reason
            assert expected in status['message'], status['message']
    finally:
        assert all(
            r.successful
            for r in probe.set_parameters(
                {'semantic.label_scheme': 'auto', 'label_source': 'auto'}
            )
        )
    assert int(status['frames_malformed']) >= len(cases)
    # The node still answers the next good pair; scans with some NaN points are fine.
    with_nan = dataclasses.replace(
        scene,
        pts_src=np.concatenate([scene.pts_src, nan_points]),
        label_src=np.concatenate([scene.label_src, np.ones(100)]),
    )
    _, src_stamp, status = send_pair(probe, with_nan)
    assert status['level'] == 0, status['message']
    assert int(status['dropped_nonfinite_points']) == 100
    assert_close_to(matrix(probe.wait_for('transform', src_stamp, 5.0).transform), scene.trans_gt)


def test_organized_cloud_with_row_padding_and_float_labels(probe: NodeProbe, scene: Any) -> None:
    send(probe, scene.pts_dst, scene.label_dst)
    # The current scan as a 2-row organized cloud, 8 bytes of padding per row, float64 labels.
    msg = probe.cloud(
        scene.pts_src, scene.label_src.astype(np.float64), _next_stamp(), label_datatype='float64'
    )
    assert msg.fields[-1].datatype == FLOAT64
    width = msg.width // 2
    rows = np.frombuffer(bytes(msg.data), np.uint8)[: 2 * width * msg.point_step]
    rows = rows.reshape(2, width * msg.point_step)
    padded = np.concatenate([rows, np.full((2, 8), 0xEE, np.uint8)], axis=1)
    msg.height, msg.width, msg.row_step = 2, width, width * msg.point_step + 8
    msg.data = padded.tobytes()
    probe.publish(msg)
    status = probe.status_for(msg.header.stamp, TIMEOUT_S)
    assert status['level'] == 0, status['message']
    assert_close_to(
        matrix(probe.wait_for('transform', msg.header.stamp, 5.0).transform), scene.trans_gt
    )


def test_failure_keeps_the_keyframe_and_does_not_move_the_odometry(
    probe: NodeProbe, scene: Any
) -> None:
    dst_stamp, _ = send(probe, scene.pts_dst, scene.label_dst)
    # the first keyframe's pair would refine itself and stage 9 could accept it on its own
    # evidence (odometry.refine_first_keyframe): this test forces the refusal
    # (and keyframe.max_failures 0: a refused first pair would otherwise make the refused
    # scan the keyframe at once, issue 29; failures.py)
    forced = {
        'estimator.min_inliers': 100000,
        'odometry.refine_first_keyframe': False,
        'keyframe.max_failures': 0,
    }
    assert all(r.successful for r in probe.set_parameters(forced))
    try:
        failed_stamp, status = send(probe, scene.pts_src, scene.label_src)
    finally:
        defaults = {
            'estimator.min_inliers': RegistrationConfig().estimator.min_inliers,
            'odometry.refine_first_keyframe': True,
            'keyframe.max_failures': RegistrationConfig().keyframe.max_failures,
        }
        assert all(r.successful for r in probe.set_parameters(defaults))
    assert status['level'] == 1 and 'registration failed' in status['message']
    assert 'estimator.min_inliers' in status['message']
    # a refused estimate goes on to the BEV search, which is reported and refused too
    assert float(status['stage.register.bev_search_ms']) > 0.0
    assert int(status['bev_search_peaks']) > 0 and 'bev_search_score' in status
    assert probe.wait_for('transform', failed_stamp, 1.0) is None
    assert probe.wait_for('odometry', failed_stamp, 0.5) is None
    src_stamp, status = send(probe, scene.pts_src, scene.label_src)  # tries again
    assert status['level'] == 0, status['message']
    assert status['keyframe_stamp'] == f'{dst_stamp.sec + 1e-9 * dst_stamp.nanosec:.9f}'
    odom = probe.wait_for('odometry', src_stamp, 5.0)
    assert_close_to(matrix(odom.pose.pose), scene.trans_gt)


def test_distance_keyframe_policy_and_reset(probe: NodeProbe, scene: Any) -> None:
    assert all(
        r.successful
        for r in probe.set_parameters(
            {'keyframe.policy': 'distance', 'keyframe.min_distance': 50.0}
        )
    )
    try:
        dst_stamp, _, _ = send_pair(probe, scene)
        again, status = send(probe, scene.pts_src, scene.label_src)  # 2.5 m < 50 m: same keyframe
        assert status['keyframe_stamp'] == f'{dst_stamp.sec + 1e-9 * dst_stamp.nanosec:.9f}'
        assert_close_to(matrix(probe.wait_for('transform', again, 5.0).transform), scene.trans_gt)
    finally:
        assert all(
            r.successful
            for r in probe.set_parameters(
                {'keyframe.policy': 'every_frame', 'keyframe.min_distance': 1.0}
            )
        )
    assert probe.reset()
    stamp, status = send(probe, scene.pts_src, scene.label_src)
    assert 'first scan' in status['message']
    odom = probe.wait_for('odometry', stamp, 5.0)
    np.testing.assert_allclose(matrix(odom.pose.pose), np.eye(4), atol=1e-9)
    assert len(probe.wait_for('path', stamp, 5.0).poses) == 1


def test_label_scheme_change_that_invalidates_the_keyframe_restarts(
    probe: NodeProbe, scene: Any
) -> None:
    from mlsemreg_ros.core.matching.labels import LabelMap

    raw = LabelMap.load().to_raw(scene.label_dst)  # raw ids (car 10, road 40, ...)
    send(probe, scene.pts_dst, raw)
    assert all(r.successful for r in probe.set_parameters({'semantic.label_scheme': 'learning'}))
    try:
        _, status = send(probe, scene.pts_src, scene.label_src)
    finally:
        probe.reset()
        assert all(r.successful for r in probe.set_parameters({'semantic.label_scheme': 'auto'}))
    assert status['level'] == 0 and 'first scan' in status['message']


# -- issue 11: named regressions through the real node ---------------------------------
def test_a_degenerate_first_scan_does_not_become_the_keyframe(
    probe: NodeProbe, scene: Any
) -> None:
    for points in (scene.pts_dst[:1], scene.pts_dst[:12], np.repeat(scene.pts_dst[:1], 500, 0)):
        _, status = send(
            probe,
            points,
            scene.label_dst[: len(points)] if len(points) <= 12 else np.full(len(points), 9),
        )
        assert status['level'] == 1 and 'no keyframe yet' in status['message']
    _, src_stamp, status = send_pair(probe, scene)  # not stuck: the next good pair
    assert status['level'] == 0, status['message']
    assert_close_to(matrix(probe.wait_for('transform', src_stamp, 5.0).transform), scene.trans_gt)


def test_a_flat_first_scan_waits_and_a_degenerate_scan_in_the_middle_is_bridged(
    probe: NodeProbe, scene: Any
) -> None:
    """Issue 29: no keyframe without structure; the scan after a degenerate one registers."""
    rng = np.random.default_rng(0)
    ground = np.c_[rng.uniform(-30, 30, (20000, 2)), rng.normal(0.0, 0.02, 20000)]
    _, status = send(probe, ground, np.full(len(ground), 9))
    assert status['level'] == 1 and 'no keyframe yet' in status['message']
    assert 'too little structure' in status['message']
    _, status = send(probe, scene.pts_dst, scene.label_dst)
    assert status['level'] == 0 and 'first scan' in status['message'], status['message']
    _, status = send(probe, scene.pts_dst[:3], scene.label_dst[:3])  # a degenerate scan
    assert status['level'] == 1, status['message']
    src_stamp, status = send(probe, scene.pts_src, scene.label_src)
    assert status['level'] == 0, status['message']
    assert_close_to(matrix(probe.wait_for('transform', src_stamp, 5.0).transform), scene.trans_gt)


def test_duplicate_stamps_are_skipped_and_backward_stamps_restart(
    probe: NodeProbe, scene: Any
) -> None:
    dst_stamp, status = send(probe, scene.pts_dst, scene.label_dst)
    probe.publish(probe.cloud(scene.pts_src, scene.label_src.astype(np.uint32), dst_stamp))
    status = probe.status_for(dst_stamp, TIMEOUT_S, skip=1)
    assert status is not None and status['level'] == 1
    assert 'duplicate stamp' in status['message']
    earlier = to_stamp(1.0)  # before every stamp of this module: a bag that loops
    probe.publish(probe.cloud(scene.pts_src, scene.label_src.astype(np.uint32), earlier))
    status = probe.status_for(earlier, TIMEOUT_S)
    assert 'first scan' in status['message'] and 'went backwards' in status['message']
    odom = probe.wait_for('odometry', earlier, 5.0)
    np.testing.assert_allclose(matrix(odom.pose.pose), np.eye(4), atol=1e-9)


def test_a_frame_id_change_restarts_the_odometry(probe: NodeProbe, scene: Any) -> None:
    send_pair(probe, scene)
    stamp = _next_stamp()
    probe.publish(
        probe.cloud(scene.pts_src, scene.label_src.astype(np.uint32), stamp, frame_id='os_sensor')
    )
    status = probe.status_for(stamp, TIMEOUT_S)
    assert 'first scan' in status['message'] and int(status['frame_changes']) >= 1
    assert probe.wait_for('odometry', stamp, 5.0).child_frame_id == 'os_sensor'
    assert all(r.successful for r in probe.set_parameters({'frame_change': 'skip'}))
    try:
        other = _next_stamp()
        probe.publish(probe.cloud(scene.pts_dst, scene.label_dst.astype(np.uint32), other))
        status = probe.status_for(other, TIMEOUT_S)
        assert status['level'] == 1 and 'frame_change: skip' in status['message']
    finally:
        assert all(r.successful for r in probe.set_parameters({'frame_change': 'reset'}))


def test_input_the_old_node_got_wrong_now_registers(probe: NodeProbe, scene: Any) -> None:
    """One label 20, a signed raw label -2^31, a point at 1e30, a count-0 intensity field."""
    from mlsemreg_ros.core.matching.labels import LabelMap

    raw_dst = LabelMap.load().to_raw(scene.label_dst).astype(np.int64)
    raw_dst[0] = -(2**31)  # instance bits only, class 0: valid
    dst = probe.cloud(
        scene.pts_dst, raw_dst.astype(np.int32), _next_stamp(), label_datatype='int32'
    )
    labels_src = scene.label_src.astype(np.uint32)
    labels_src[0] = 20  # one value outside the learning ids
    points_src = scene.pts_src.copy()
    points_src[1] = 1e30  # one absurd point
    src = probe.cloud(points_src, labels_src, _next_stamp())
    fields = list(src.fields)
    fields.append(type(fields[0])(name='intensity', offset=0, datatype=7, count=0))
    src.fields = fields
    for msg in (dst, src):
        probe.publish(msg)
        status = probe.status_for(msg.header.stamp, TIMEOUT_S)
        assert status['level'] == 0, status['message']
    assert status['mode'] == 'ml-semreg' and status['input.label_scheme'] == 'learning'
    assert int(status['input.labels_out_of_scheme']) == 1
    assert int(status['input.dropped_far']) == 1
    assert_close_to(
        matrix(probe.wait_for('transform', src.header.stamp, 5.0).transform), scene.trans_gt
    )


def test_the_local_map_is_published_only_while_subscribed(probe: NodeProbe, scene: Any) -> None:
    from mlsemreg_ros.codec.pointcloud2 import pointcloud2_to_arrays
    from sensor_msgs.msg import PointCloud2

    clouds: list[Any] = []
    subscription = probe.node.create_subscription(
        PointCloud2, 'mlsemreg/local_map', clouds.append, 1
    )
    try:
        assert probe.wait_until(
            lambda: probe.node.count_publishers('mlsemreg/local_map') > 0, 10.0
        )
        send_pair(probe, scene)
        assert probe.wait_until(lambda: bool(clouds), 10.0), 'no mlsemreg/local_map'
        cloud = clouds[-1]
        assert cloud.header.frame_id == 'odom'
        xyz = pointcloud2_to_arrays(cloud, 'label', require_labels=False).xyz
        assert xyz.shape[0] > 1000 and np.isfinite(xyz).all()
    finally:
        probe.node.destroy_subscription(subscription)


def velodyne_cloud(probe: NodeProbe, points: np.ndarray, stamp: Any) -> Any:
    """
    Build a PointCloud2 as a Velodyne driver publishes it: no label field.

    x, y, z, intensity (float32), ring (uint16) and time (float32, s after the stamp),
    22 bytes a point.
    """
    from std_msgs.msg import Header

    cloud_cls, field_cls = probe._msg_classes
    layout = np.dtype(
        {
            'names': ['x', 'y', 'z', 'intensity', 'ring', 'time'],
            'formats': ['<f4', '<f4', '<f4', '<f4', '<u2', '<f4'],
            'offsets': [0, 4, 8, 12, 16, 18],
            'itemsize': 22,
        }
    )
    data = np.zeros(len(points), dtype=layout)
    for k, axis in enumerate('xyz'):
        data[axis] = points[:, k]
    data['intensity'] = 10.0
    data['ring'] = np.arange(len(points)) % 64
    data['time'] = (np.arctan2(points[:, 1], points[:, 0]) + np.pi) / (2 * np.pi) * 0.1
    fields = [
        field_cls(name=name, offset=offset, datatype=datatype, count=1)
        for name, offset, datatype in (
            ('x', 0, 7),
            ('y', 4, 7),
            ('z', 8, 7),
            ('intensity', 12, 7),
            ('ring', 16, 4),
            ('time', 18, 7),
        )
    ]
    return cloud_cls(
        header=Header(stamp=stamp, frame_id='velodyne'),
        height=1,
        width=len(points),
        fields=fields,
        is_bigendian=False,
        point_step=22,
        row_step=22 * len(points),
        data=data.tobytes(),
        is_dense=True,
    )


def test_an_unlabeled_velodyne_cloud_is_registered_with_defaults(
    defaults: NodeProbe, scene: Any
) -> None:
    """No label field (x, y, z, intensity, ring, time): label_source auto labels by geometry."""
    probe = defaults
    statuses = []
    for points in (scene.pts_dst, scene.pts_src):
        msg = velodyne_cloud(probe, points, _next_stamp())
        probe.publish(msg)
        status = probe.status_for(msg.header.stamp, TIMEOUT_S)
        assert status is not None, 'no diagnostics for the scan'
        assert status['level'] == 0, status['message']
        assert status['label_source'] == 'geometric'
        statuses.append((msg.header.stamp, status))
    stamp, _ = statuses[-1]
    assert_close_to(matrix(probe.wait_for('transform', stamp, 5.0).transform), scene.trans_gt)
    # label_source field: the same cloud is skipped, and says why
    assert all(r.successful for r in probe.set_parameters({'label_source': 'field'}))
    try:
        msg = velodyne_cloud(probe, scene.pts_src, _next_stamp())
        probe.publish(msg)
        status = probe.status_for(msg.header.stamp, TIMEOUT_S)
        assert status['level'] == 1 and 'missing label field' in status['message']
    finally:
        assert all(r.successful for r in probe.set_parameters({'label_source': 'auto'}))


# -- issue 29: the real dev chain through the node -------------------------------------------
DEGENERATE = (np.array([[5.0, 0.0, 0.0], [0.0, 5.0, 0.0], [5.0, 5.0, 1.0]]), np.full(3, 40))


def _dev_chain() -> tuple[list[tuple[np.ndarray, np.ndarray]], list[np.ndarray]]:
    """Return the 11 scans of the chained dev pairs (~20 m apart) and their poses."""
    from dev_pairs import dev_pair_files

    pairs = [load_pair(path) for path in dev_pair_files()]  # skips without them
    scans = [(pairs[0].pts_src, pairs[0].label_src)] + [(p.pts_dst, p.label_dst) for p in pairs]
    poses = [np.eye(4)]
    for pair in pairs:  # trans_gt: T_dst_src, and the next scan is the dst
        poses.append(poses[-1] @ np.linalg.inv(pair.trans_gt))
    return scans, poses


def _stream(probe: NodeProbe, feed: list[tuple[int | None, Any, Any]]) -> list[tuple]:
    """Publish (chain index or None, points, labels, stamp); (index, accepted, odom pose)."""
    out = []
    for index, points, labels, stamp in feed:
        probe.publish(probe.cloud(points, np.asarray(labels).astype(np.uint32), stamp))
        status = probe.status_for(stamp, TIMEOUT_S)
        assert status is not None, 'no diagnostics for the scan'
        accepted = status['level'] == 0
        odom = probe.wait_for('odometry', stamp, 5.0) if accepted else None
        out.append((index, accepted, matrix(odom.pose.pose) if odom else None, status['message']))
    return out


def _judged(steps: list[tuple], poses: list[np.ndarray]) -> tuple[int, list]:
    """Count the chain scans accepted right (pose relative to the last accepted one); wrong."""
    right, wrong, last = 0, [], None
    for index, accepted, pose, message in steps:
        if index is None or not accepted:
            continue
        if last is not None:
            truth = np.linalg.inv(poses[last[0]]) @ poses[index]
            estimate = np.linalg.inv(last[1]) @ pose
            re = rotation_error_deg(estimate[:3, :3], truth[:3, :3])
            te = translation_error_m(estimate[:3, 3], truth[:3, 3])
            if re > 5.0 or te > 0.6:
                wrong.append((index, te, re, message))
                continue
        right += 1
        last = (index, pose)
    return right, wrong


@pytest.mark.slow
def test_the_dev_chain_after_a_degenerate_first_scan(defaults: NodeProbe) -> None:
    """Issue 29: a degenerate first scan, then >= 8 of the next 10 real scans right, 0 wrong."""
    scans, poses = _dev_chain()
    feed = [(None, *DEGENERATE, _next_stamp())]
    feed += [(k, *scans[k], _next_stamp()) for k in range(10)]
    steps = _stream(defaults, feed)
    assert not steps[0][1] and 'no keyframe yet' in steps[0][3]
    right, wrong = _judged(steps, poses)
    assert right >= 8 and not wrong, (right, wrong, [s[3] for s in steps])


@pytest.mark.slow
def test_the_dev_chain_registers_the_scan_after_a_degenerate_one(defaults: NodeProbe) -> None:
    """Issue 29: a degenerate message between two real scans; the scan after it registers."""
    scans, poses = _dev_chain()
    feed = [(k, *scans[k], _next_stamp()) for k in range(6)]
    last = feed[-1][3]
    feed.append((None, *DEGENERATE, to_stamp(last.sec + 1e-9 * last.nanosec + 0.05)))
    feed += [(k, *scans[k], _next_stamp()) for k in (6, 7)]
    steps = _stream(defaults, feed)
    assert not steps[6][1]  # the degenerate scan
    assert steps[7][1], steps[7][3]  # the scan after it
    right, wrong = _judged(steps, poses)
    assert right == 8 and not wrong, (right, wrong, [s[3] for s in steps])


@pytest.mark.slow
def test_the_dev_chain_after_a_scan_lost_in_place(defaults: NodeProbe) -> None:
    """
    Issue 29: scan 5 replaced by a degenerate one (its stamp): 0 wrong, and scan 6 registers.

    Scan 6 is then 40 m from every scan the odometry has. The seeded search around its
    prediction (core/odometry/seeded_search.py) accepts it on its covisible overlap with the
    keyframe, and the chain goes on: 10 right, 0 wrong (before it: 5 right, then stalled).
    """
    scans, poses = _dev_chain()
    feed = [(k, *scans[k], _next_stamp()) for k in range(5)]
    feed.append((None, *DEGENERATE, _next_stamp()))  # in place of scan 5
    feed += [(k, *scans[k], _next_stamp()) for k in range(6, 11)]
    steps = _stream(defaults, feed)
    assert not steps[5][1]  # the degenerate scan
    right, wrong = _judged(steps, poses)
    assert not wrong, (wrong, [s[3] for s in steps])
    assert steps[6][1], steps[6][3]
    assert right == 10, (right, [s[3] for s in steps])

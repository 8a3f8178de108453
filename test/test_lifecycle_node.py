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
mlsemreg_lifecycle_node with the real rclpy: transitions in order work, out of order fail.

Driven over the lifecycle services (``mlsemreg_node/change_state``, ``get_state``) as
Nav2's lifecycle_manager drives it; a scan is registered only while active.
"""

from __future__ import annotations

import threading
from typing import Any

from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair
from mlsemreg_ros.ros.probe import NodeProbe, to_stamp
import numpy as np
import pytest
from ros_domains import domain_id

pytestmark = pytest.mark.usefixtures('rclpy_module')  # skip without rclpy (conftest.py)

TIMEOUT_S = 60.0


@pytest.fixture(scope='module')
def managed() -> Any:
    """Run the managed node and a probe in a private context; yield (node, probe)."""
    from mlsemreg_ros.ros.lifecycle_node import MlSemRegLifecycleNode
    import rclpy
    from rclpy.executors import MultiThreadedExecutor

    context = rclpy.Context()
    rclpy.init(
        context=context,
        domain_id=domain_id('lifecycle'),
        args=['--ros-args', '-p', 'keypoints.count:=1500'],
    )
    executor = MultiThreadedExecutor(num_threads=2, context=context)
    node = probe = None
    try:
        node = MlSemRegLifecycleNode(context=context)
        probe = NodeProbe(context)
        executor.add_node(node)
        executor.add_node(probe.node)
        threading.Thread(target=executor.spin, daemon=True).start()
        yield node, probe
    finally:
        executor.shutdown(timeout_sec=5.0)
        if probe is not None:
            probe.node.destroy_node()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


class Lifecycle:
    """Calls the node's lifecycle services from the probe."""

    def __init__(self, probe: NodeProbe) -> None:
        from lifecycle_msgs.srv import ChangeState, GetState

        self.probe = probe
        self._change = probe.node.create_client(ChangeState, 'mlsemreg_node/change_state')
        self._get = probe.node.create_client(GetState, 'mlsemreg_node/get_state')
        assert self._change.wait_for_service(timeout_sec=20.0)
        assert self._get.wait_for_service(timeout_sec=20.0)

    def _call(self, client: Any, request: Any) -> Any:
        future = client.call_async(request)
        assert self.probe.wait_until(lambda: future.done(), 120.0), f'no answer to {request}'
        return future.result()

    def state(self) -> str:
        from lifecycle_msgs.srv import GetState

        return self._call(self._get, GetState.Request()).current_state.label

    def change(self, transition: str) -> bool:
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState

        request = ChangeState.Request()
        request.transition.id = getattr(Transition, f'TRANSITION_{transition.upper()}')
        return bool(self._call(self._change, request).success)


_stamps = iter(range(100, 10000))


def send(probe: NodeProbe, timeout: float) -> dict | None:
    pair = synthetic_pair(seed=0)
    stamp = to_stamp(next(_stamps) * 0.1)
    probe.publish(probe.cloud(pair.pts_dst, pair.label_dst.astype(np.uint32), stamp))
    return probe.status_for(stamp, timeout)


def subscribed(probe: NodeProbe) -> bool:
    return probe.wait_until(lambda: probe._publisher.get_subscription_count() > 0, 20.0)


def topics(node: Any) -> set[str]:
    """Return the names the node itself subscribes and publishes, not the whole graph's."""
    return {e.topic_name for e in (*node.subscriptions, *node.publishers)}


def test_transitions_in_order_work_and_out_of_order_are_refused(managed: Any) -> None:
    node, probe = managed
    lifecycle = Lifecycle(probe)
    assert lifecycle.state() == 'unconfigured'
    assert '/points' not in topics(node)  # nothing exists before configure
    assert not lifecycle.change('activate'), 'activated while unconfigured'
    assert not lifecycle.change('deactivate')
    assert lifecycle.state() == 'unconfigured'

    assert lifecycle.change('configure')
    assert lifecycle.state() == 'inactive'
    assert {'/points', '/mlsemreg/odometry'} <= topics(node)
    assert not lifecycle.change('configure'), 'configured twice'
    assert subscribed(probe)
    assert send(probe, 3.0) is None, 'an inactive node registered a scan'

    assert lifecycle.change('activate')
    assert lifecycle.state() == 'active'
    assert not lifecycle.change('cleanup'), 'cleaned up while active'
    status = send(probe, TIMEOUT_S)
    assert status is not None and status['level'] == 0, status

    assert lifecycle.change('deactivate')
    assert lifecycle.state() == 'inactive'
    assert send(probe, 3.0) is None, 'a deactivated node registered a scan'

    assert lifecycle.change('cleanup')
    assert lifecycle.state() == 'unconfigured'
    assert not {'/points', '/mlsemreg/odometry'} & topics(node)

    assert lifecycle.change('configure'), 'not configurable again after cleanup'
    assert lifecycle.change('activate')
    assert subscribed(probe)
    assert send(probe, TIMEOUT_S) is not None
    assert lifecycle.change('deactivate')
    assert lifecycle.change('cleanup')
    assert lifecycle.change('unconfigured_shutdown')
    assert lifecycle.state() == 'finalized'
    assert not lifecycle.change('configure'), 'configured after shutdown'

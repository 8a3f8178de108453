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
``mlsemreg_lifecycle_node``: the same node as ``mlsemreg_node``, managed (rclpy.lifecycle).

It is :class:`~mlsemreg_ros.ros.node.MlSemRegNode` on a ``LifecycleNode`` base (every
callback, topic and parameter is the plain node's); only when things happen differs, as
Nav2's ``lifecycle_manager`` expects (docs/ros_interface.md, *Managed node*):

- constructed (``unconfigured``): the parameters are declared, nothing else exists;
- ``configure``: the odometry, topics, services and the worker are created (invalid
  parameters fail the transition, the node stays unconfigured);
- ``activate``: scans on ``points`` are registered (inactive, they are counted in
  ``frames_inactive`` and dropped; the heartbeat goes on);
- ``deactivate``: scans are dropped again, the odometry state is kept;
- ``cleanup``: the worker stops and everything ``configure`` created is destroyed;
- ``shutdown``: as cleanup, from any state.

A transition out of order (e.g. ``activate`` while unconfigured) is refused by the
lifecycle state machine.
"""

from __future__ import annotations

from collections.abc import Callable
import signal
import threading
import time
from typing import Any

from mlsemreg_ros.core.config import ConfigError, NODE_NAME
from mlsemreg_ros.ros.callback_guard import spin_guarded
from mlsemreg_ros.ros.node import MlSemRegNode, SPIN_PERIOD_S
import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.lifecycle import LifecycleNode, State, TransitionCallbackReturn
from rclpy.signals import SignalHandlerOptions


class MlSemRegLifecycleNode(MlSemRegNode, LifecycleNode):
    """The managed ``mlsemreg_node`` (module docstring)."""

    _configure_at_start = False

    def __init__(self, **kwargs: Any) -> None:
        """Declare the parameters; the rest waits for ``configure``."""
        self._active = False
        super().__init__(**kwargs)
        service = getattr(self, '_service_change_state', None)
        if service is not None:  # answer an invalid transition instead of raising
            service.callback = refuse_invalid_transitions(service.callback, self.get_logger())

    def on_configure(self, state: State) -> TransitionCallbackReturn:
        """Create the odometry, the interface and the worker."""
        try:
            self._setup(time.perf_counter())
        except (ConfigError, ParameterException, ValueError) as error:
            self.get_logger().error(f'configure failed: {error}')
            self._teardown()
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: State) -> TransitionCallbackReturn:
        """Take scans."""
        self._active = True
        self.get_logger().info('active: registering scans')
        return super().on_activate(state)

    def on_deactivate(self, state: State) -> TransitionCallbackReturn:
        """Drop scans; the odometry keeps its state."""
        self._active = False
        self.get_logger().info('inactive: scans are dropped')
        return super().on_deactivate(state)

    def on_cleanup(self, state: State) -> TransitionCallbackReturn:
        """Stop the worker and destroy what configure created."""
        self._active = False
        self._teardown()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: State) -> TransitionCallbackReturn:
        """Cleanup from any state."""
        self._active = False
        self._teardown()
        return TransitionCallbackReturn.SUCCESS


def refuse_invalid_transitions(callback: Callable[..., Any], logger: Any) -> Callable[..., Any]:
    """
    Wrap rclpy's ``change_state`` callback: an invalid transition answers ``success: false``.

    rclpy (Jazzy) raises from the service callback when the state machine has no such
    transition from the current state: the request is never answered (a caller such as
    Nav2's lifecycle_manager waits) and an executor without a guard stops spinning.
    """

    def change_state(request: Any, response: Any) -> Any:
        try:
            return callback(request, response)
        except _rclpy.RCLError as error:
            logger.warning(f'transition {request.transition.id} refused: {error}')
            response.success = False
            return response

    return change_state


def main(args: list[str] | None = None) -> int:
    """Console script ``mlsemreg_lifecycle_node`` (signals as in ``mlsemreg_node``)."""
    stop = threading.Event()
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    for sig in handlers:
        signal.signal(sig, lambda *_: stop.set())
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        node = MlSemRegLifecycleNode()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        spin_guarded(
            executor,
            lambda: not stop.is_set() and rclpy.ok(),
            node.callback_drops,
            SPIN_PERIOD_S,
        )
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ConfigError, ParameterException) as error:
        rclpy.logging.get_logger(NODE_NAME).fatal(f'invalid parameters: {error}')
        return 1
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())

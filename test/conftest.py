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
Shared fixtures: rclpy in a private context, and the environment every rclpy test needs.

The rmw implementation and the discovery range are read when rclpy is first imported or
initialized, so they are set here, before any test module imports rclpy.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
import contextlib
import os
from typing import Any

import pytest

os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


@pytest.fixture(scope='session')
def rclpy_module() -> Any:
    """Return the rclpy module, or skip when the ROS 2 Jazzy wheels are not installed."""
    return pytest.importorskip('rclpy', reason='rclpy (ROS 2 Jazzy wheels) not installed')


@pytest.fixture(scope='session')
def ros_context(rclpy_module: Any) -> Callable[..., contextlib.AbstractContextManager[Any]]:
    """
    Return a factory of initialized rclpy contexts, used as ``with factory(domain_id)``.

    Each use gets its own ``rclpy.Context`` on ``domain_id`` (see ros_domains.py), shut down
    on exit (``try_shutdown``, as Jazzy wants instead of ``with rclpy.init()``).
    """

    @contextlib.contextmanager
    def context(domain_id: int, args: list[str] | None = None) -> Iterator[Any]:
        ctx = rclpy_module.Context()
        rclpy_module.init(context=ctx, domain_id=domain_id, args=args)
        try:
            yield ctx
        finally:
            rclpy_module.try_shutdown(context=ctx)

    return context


@pytest.fixture
def not_installed(monkeypatch: pytest.MonkeyPatch) -> Callable[[str], None]:
    """Return a function that makes ``importlib.util.find_spec`` miss one module by name."""
    import importlib.util

    real = importlib.util.find_spec

    def hide(module: str) -> None:
        monkeypatch.setattr(
            importlib.util,
            'find_spec',
            lambda name, *a: None if name == module else real(name, *a),
        )

    return hide


@pytest.fixture
def restore_threads() -> Iterator[None]:
    """Put the process-wide worker count (``core/threads.py``) back after the test."""
    from mlsemreg_ros.core import threads

    before = threads._requested
    yield
    threads.configure(before)

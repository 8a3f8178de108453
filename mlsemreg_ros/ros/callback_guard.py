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
No callback kills the node: drops counted by stream and reason, guarded callbacks, guarded spin.

Three layers (``docs/ros_interface.md``, *What the node drops*):

- **At arrival** each converter checks its message and drops what cannot be used, with a
  reason (``ros/prior_inputs.py`` for IMU and wheel odometry, the cloud decoder for
  clouds). :class:`DropCounter` counts the drops (``<stream>_dropped`` and
  ``<stream>_dropped.<reason>``, published in ``/diagnostics``) and logs them, throttled per
  stream and reason.
- **Every callback** the node registers (subscriptions, services, the parameter on-set
  callback) is wrapped by :class:`GuardedCallbacks`: an exception that escapes a converter
  is logged and counted (``callback_errors``, ``callback_errors.<name>``); a service
  answers ``success: false`` with the error, a parameter change is refused with it.
- **The executor** is spun by :func:`spin_guarded`: an exception that still reaches it is
  logged and counted the same way, and spinning goes on.

The layers are independent of rclpy (duck-typed), so they are tested without it.
"""

from __future__ import annotations

import collections
from collections.abc import Callable
import functools
import threading
import time
from typing import Any

#: Log the drops of one (stream, reason) at most this often (s); the count says how many.
LOG_PERIOD_S = 5.0
#: The ``/diagnostics`` key of the exceptions the guards caught.
CALLBACK_ERRORS = 'callback_errors'


class DropCounter:
    """Thread-safe counts of dropped messages by stream and reason, with a throttled log."""

    def __init__(
        self,
        log: Callable[[str], Any] | None = None,
        period_s: float = LOG_PERIOD_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """Log with ``log(text)`` (None: count only), each (stream, reason) once per period."""
        self._lock = threading.Lock()
        self._counts: collections.Counter[str] = collections.Counter()
        self._log, self._period, self._clock = log, period_s, clock
        self._logged: dict[tuple[str, str], tuple[float, int]] = {}  # last log, count then

    def drop(self, stream: str, reason: str, detail: str = '') -> None:
        """Count one dropped ``stream`` message for ``reason`` and log it (throttled)."""
        key = (stream, reason)
        with self._lock:
            self._counts[f'{stream}_dropped'] += 1
            self._counts[f'{stream}_dropped.{reason}'] += 1
            total = self._counts[f'{stream}_dropped.{reason}']
            now = self._clock()
            last, seen = self._logged.get(key, (-float('inf'), 0))
            if now - last < self._period:
                return
            self._logged[key] = (now, total)
        if self._log is not None:
            since = total - seen - 1
            more = f' ({since} more since the last report)' if since > 0 else ''
            text = f'dropped {stream} message: {reason}'
            self._log(f'{text}: {detail}{more}' if detail else f'{text}{more}')

    def error(self, name: str, error: BaseException) -> None:
        """Count and log an exception a guard caught in callback ``name``."""
        with self._lock:
            self._counts[CALLBACK_ERRORS] += 1
            self._counts[f'{CALLBACK_ERRORS}.{name}'] += 1
        self.drop_log(name, type(error).__name__, f'{name} callback failed: {error!r}')

    def drop_log(self, stream: str, reason: str, text: str) -> None:
        """Log ``text`` at most once per period for (stream, reason), without counting."""
        key = ('!' + stream, reason)
        with self._lock:
            now = self._clock()
            last, _ = self._logged.get(key, (-float('inf'), 0))
            if now - last < self._period:
                return
            self._logged[key] = (now, 0)
        if self._log is not None:
            self._log(text)

    def count(self, key: str) -> int:
        """Return the value of one key (0 if never counted)."""
        with self._lock:
            return self._counts[key]

    def snapshot(self, streams: tuple[str, ...] = ()) -> dict[str, int]:
        """Return every count; ``<stream>_dropped`` of ``streams`` and the errors even at 0."""
        with self._lock:
            counts = dict(self._counts)
        for stream in streams:
            counts.setdefault(f'{stream}_dropped', 0)
        counts.setdefault(CALLBACK_ERRORS, 0)
        return counts


def guard(
    name: str,
    callback: Callable[..., Any],
    drops: DropCounter,
    on_error: Callable[..., Any] | None = None,
) -> Callable[..., Any]:
    """
    Return ``callback`` wrapped so that it never raises.

    An exception is counted and logged by ``drops.error(name, ...)``; the wrapper then returns
    ``on_error(error, *args)`` (itself guarded: None if it raises too), or None.
    """
    if getattr(callback, '__guarded__', False):
        return callback

    @functools.wraps(callback)
    def guarded(*args: Any, **kwargs: Any) -> Any:
        try:
            return callback(*args, **kwargs)
        except Exception as error:  # the node never dies of one message
            drops.error(name, error)
            if on_error is None:
                return None
            try:
                return on_error(error, *args)
            except Exception as again:
                drops.error(name, again)
                return None

    guarded.__guarded__ = True  # type: ignore[attr-defined]
    return guarded


def failed_service(error: BaseException, *args: Any) -> Any:
    """Answer a service whose callback raised: ``success: false`` and the error, if it has them."""
    response = args[-1] if args else None
    if response is None:
        return None
    if hasattr(response, 'success'):
        response.success = False
    if hasattr(response, 'message'):
        response.message = f'failed: {type(error).__name__}: {error}'
    return response


def refused_parameters(error: BaseException, *args: Any) -> Any:
    """Refuse a parameter change whose validation raised (rcl_interfaces/SetParametersResult)."""
    from rcl_interfaces.msg import SetParametersResult

    return SetParametersResult(
        successful=False, reason=f'validation failed: {type(error).__name__}: {error}'
    )


class GuardedCallbacks:
    """
    Mixin for an rclpy Node: every subscription, service and parameter callback is guarded.

    Put it before ``Node`` in the bases. The node sets :attr:`callback_drops` (a
    :class:`DropCounter`) before it creates any callback, and may register
    :attr:`callback_fallbacks` by topic or service name (what a failed callback answers, e.g.
    a cloud's ``/diagnostics`` entry): ``fallback(error, *args)``.
    """

    callback_drops: DropCounter
    callback_fallbacks: dict[str, Callable[..., Any]]

    def _guard_drops(self) -> DropCounter:
        drops = getattr(self, 'callback_drops', None)
        if drops is None:
            drops = self.callback_drops = DropCounter()
        return drops

    def _fallback(self, name: str) -> Callable[..., Any] | None:
        return getattr(self, 'callback_fallbacks', {}).get(name)

    def create_subscription(self, msg_type: Any, topic: str, callback: Any, *args: Any, **kw: Any):
        """Create a subscription whose callback never raises (see the class)."""
        wrapped = guard(topic, callback, self._guard_drops(), self._fallback(topic))
        return super().create_subscription(msg_type, topic, wrapped, *args, **kw)

    def create_service(self, srv_type: Any, srv_name: str, callback: Any, *args: Any, **kw: Any):
        """Create a service whose callback never raises: a failure answers ``success: false``."""
        fallback = self._fallback(srv_name) or failed_service
        wrapped = guard(srv_name, callback, self._guard_drops(), fallback)
        return super().create_service(srv_type, srv_name, wrapped, *args, **kw)

    def add_on_set_parameters_callback(self, callback: Any) -> None:
        """Add an on-set callback that never raises: a failure refuses the change."""
        wrapped = guard('parameters', callback, self._guard_drops(), refused_parameters)
        return super().add_on_set_parameters_callback(wrapped)

    def add_post_set_parameters_callback(self, callback: Any) -> None:
        """Add a post-set callback that never raises (a failure is logged and counted)."""
        wrapped = guard('parameters', callback, self._guard_drops())
        return super().add_post_set_parameters_callback(wrapped)


def spin_guarded(
    executor: Any,
    keep_spinning: Callable[[], bool],
    drops: DropCounter,
    timeout_sec: float = 0.1,
) -> None:
    """
    Spin ``executor`` while ``keep_spinning()``: the last line against a raising callback.

    rclpy re-raises a callback's exception from ``spin_once``; here it is counted and logged
    by ``drops.error('executor', ...)`` and spinning goes on. Shutdown exceptions (and
    anything that is not an ``Exception``, e.g. KeyboardInterrupt) still end the loop.
    """
    shutdown = _shutdown_exceptions()
    while keep_spinning():
        try:
            executor.spin_once(timeout_sec=timeout_sec)
        except shutdown:
            raise
        except Exception as error:
            drops.error('executor', error)


def _shutdown_exceptions() -> tuple[type[BaseException], ...]:
    try:
        from rclpy.executors import ExternalShutdownException, ShutdownException
    except ImportError:  # without rclpy nothing raises them
        return ()
    return ExternalShutdownException, ShutdownException

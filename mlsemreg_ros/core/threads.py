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
Small persistent thread pools for the core's parallel sections.

NumPy ufuncs, BLAS, SciPy's KD-trees and sparse products release the GIL, so
two threads use both cores of the target machine. Each caller level (scan
preparation, Local-SS search, the matcher's chunks) owns its own pool, so a
task running on one pool may wait for another pool without deadlocking.
Pools are created on first use and forgotten in a forked child, whose copy
of the threads does not exist. Every pool honours one worker count,
:func:`configure` (the core config's ``threads``; 0 = all cores), which the
fine alignment (small_gicp's OpenMP threads) reads too through :func:`workers`.

OpenMP's waiting threads sleep at once (``OMP_WAIT_POLICY=PASSIVE``, set here before
any module loads small_gicp's OpenMP runtime, unless the environment sets it): with the
default, a thread at a barrier spins for up to 300 000 rounds while its partner waits
for a core another process holds, and on the shared 2-core machine small_gicp's
alignment to the local map took 580 ms instead of 145 ms (``docs/field.md#speed``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
import os
import threading
from typing import Any, ClassVar, TypeVar

#: OpenMP runtimes read it when they load: waiting threads sleep instead of spinning.
os.environ.setdefault('OMP_WAIT_POLICY', 'PASSIVE')

Item = TypeVar('Item')
Result = TypeVar('Result')


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity where the OS tells it)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover (not Linux)
        return max(1, os.cpu_count() or 1)


_requested = 0  # the configured thread count; 0 = all cores


def configure(threads: int) -> None:
    """Set the worker count of every pool and of the fine alignment (0: all cores)."""
    global _requested
    if threads < 0:
        raise ValueError(f'threads must be >= 0, got {threads}')
    _requested = int(threads)


def workers() -> int:
    """Return the worker count in force: the configured count, or all cores for 0."""
    return _requested if _requested > 0 else available_cores()


class LazyPool:
    """A named thread pool with :func:`workers` threads, created on first use."""

    _instances: ClassVar[list[LazyPool]] = []

    def __init__(self, name: str) -> None:
        self.name = name
        self._pool: ThreadPoolExecutor | None = None
        self._size = 0
        self._lock = threading.Lock()
        LazyPool._instances.append(self)

    def run(self, function: Callable[[Item], Result], items: Sequence[Item]) -> list[Result]:
        """Return ``[function(x) for x in items]``, on the pool when there is more than one."""
        size = workers()
        if min(len(items), size) <= 1:
            return [function(x) for x in items]
        return list(self._executor(size).map(function, items))

    def submit(self, function: Callable[[], Result]) -> Future[Result] | None:
        """Start ``function()`` on the pool and return its future (None with one worker)."""
        size = workers()
        if size <= 1:
            return None
        return self._executor(size).submit(function)

    def _executor(self, size: int) -> ThreadPoolExecutor:
        """Return the pool, created (or resized) to ``size`` threads."""
        with self._lock:
            if self._pool is None or self._size != size:
                if self._pool is not None:  # resized: running tasks finish on the old one
                    self._pool.shutdown(wait=False)
                self._pool, self._size = (
                    ThreadPoolExecutor(size, thread_name_prefix=self.name),
                    size,
                )
            return self._pool

    def _forget(self) -> None:
        self._pool, self._lock = None, threading.Lock()

    @classmethod
    def _forget_all(cls) -> None:
        for pool in cls._instances:
            pool._forget()


def _after_fork() -> Any:
    LazyPool._forget_all()


os.register_at_fork(after_in_child=_after_fork)

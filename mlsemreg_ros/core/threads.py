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
of the threads does not exist.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
import os
import threading
from typing import Any, ClassVar, TypeVar

Item = TypeVar('Item')
Result = TypeVar('Result')


class LazyPool:
    """A named thread pool of at most ``workers`` threads, created on first use."""

    _instances: ClassVar[list[LazyPool]] = []

    def __init__(self, name: str, workers: int = 2) -> None:
        self.name, self.workers = name, workers
        self._pool: ThreadPoolExecutor | None = None
        self._lock = threading.Lock()
        LazyPool._instances.append(self)

    def run(self, function: Callable[[Item], Result], items: Sequence[Item]) -> list[Result]:
        """Return ``[function(x) for x in items]``, on the pool when there is more than one."""
        workers = max(1, min(len(items), os.cpu_count() or 1, self.workers))
        if workers == 1:
            return [function(x) for x in items]
        with self._lock:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(self.workers, thread_name_prefix=self.name)
        return list(self._pool.map(function, items))

    def _forget(self) -> None:
        self._pool, self._lock = None, threading.Lock()

    @classmethod
    def _forget_all(cls) -> None:
        for pool in cls._instances:
            pool._forget()


def _after_fork() -> Any:
    LazyPool._forget_all()


os.register_at_fork(after_in_child=_after_fork)

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
Values computed once, when first read: the geometric labels of a tracked scan.

The odometry tracks most scans by the fine alignment alone, which reads points, never
labels. A scan's computed labels are read when a global registration matches it (Group
Matching, Eqs. 3-6), when a map stores it, or when the registered cloud is published. A
:class:`Deferred` holds how to compute them; :func:`deferred_attribute` turns a dataclass
field into a property that resolves a :class:`Deferred` on first read and keeps the
value, so every reader sees an array (docs/labels.md, "Labels when they are read").
"""

from __future__ import annotations

from collections.abc import Callable
import threading
from typing import Any, Generic, TypeVar

Value = TypeVar('Value')

_MISSING = object()


class Deferred(Generic[Value]):
    """A value computed by ``compute()`` on the first :meth:`get` (once, thread-safe)."""

    __slots__ = ('_compute', '_lock', '_value')

    def __init__(self, compute: Callable[[], Value]) -> None:
        self._compute: Callable[[], Value] | None = compute
        self._lock = threading.Lock()
        self._value: Any = _MISSING

    @property
    def ready(self) -> bool:
        """Whether the value has been computed."""
        return self._value is not _MISSING

    def get(self) -> Value:
        """Return the value, computing it on the first call (a failed one is tried again)."""
        if self._value is _MISSING:
            with self._lock:
                if self._value is _MISSING:
                    compute = self._compute
                    assert compute is not None
                    self._value = compute()  # raises without a value: the next read retries
                    self._compute = None  # what it held (the scan) is freed
        return self._value

    def then(self, function: Callable[[Value], Any]) -> Deferred[Any]:
        """Return a deferred value of ``function(self.get())``."""
        return Deferred(lambda: function(self.get()))


def resolved(value: Any) -> Any:
    """Return ``value``, or its computed value if it is a :class:`Deferred`."""
    return value.get() if isinstance(value, Deferred) else value


def stored(owner: Any, name: str) -> Any:
    """Return the attribute ``name`` of ``owner`` as stored: a :class:`Deferred` stays one."""
    key, values = f'_{name}', getattr(owner, '__dict__', {})
    return values[key] if key in values else getattr(owner, name, None)


def deferred_attribute(cls: type, name: str) -> type:
    """
    Make the dataclass field ``name`` of ``cls`` accept a :class:`Deferred`.

    The field keeps its place in ``__init__``; reading it returns the computed value (and
    keeps it), :func:`stored` returns what was stored. Call after ``@dataclass``.
    """
    key = f'_{name}'

    def read(self: Any) -> Any:
        value = self.__dict__[key]
        if isinstance(value, Deferred):
            value = value.get()
            self.__dict__[key] = value
        return value

    def write(self: Any, value: Any) -> None:
        self.__dict__[key] = value

    setattr(cls, name, property(read, write, doc=f'``{name}``, computed on first read'))
    if '__getstate__' not in cls.__dict__:  # pickles the value, not how to compute it

        def getstate(self: Any) -> dict[str, Any]:
            getattr(self, name)
            return dict(self.__dict__)

        cls.__getstate__ = getstate  # type: ignore[attr-defined]
    return cls

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
The sweep alignment of a tracked scan started as soon as its map alignment is done.

A scan tracked by its prediction is aligned to the map (small_gicp, which holds the GIL),
then judged by the trust rules and the decision (Python, 0.3-0.4 ms on a solid-state scan),
and only then is its sweep aligned (``Tracker.align_sweep``: a compiled Gauss-Newton
without the GIL, 0.9-1.2 ms). The sweep alignment's inputs are known when the map
alignment ends: the scan, its deskew twist, the map's Gaussians, the refined prediction's
pose and the twist that pose implies. So :meth:`SweepAhead.start` runs the same call
(:func:`~mlsemreg_ros.core.odometry.sweep_starts.align_from_starts`) on a second thread
right then, beside the rules, and :meth:`SweepAhead.take` hands its result to the sweep
alignment when that asks with the same inputs (the same scan object, a bitwise equal pose
and implied twist, the same Gaussians and settings): the same function of the same arrays,
so the same poses (docs/sensors.md, session 22). Any other ask (a global or rotated pose, a
scan deskewed again, the first pair's deskew, a steady scan) computes as before; the result
started ahead is dropped. Nothing with one worker (``threads: 1``).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, replace
import threading
from typing import Any

from mlsemreg_ros.core import threads
from mlsemreg_ros.core.alignment.config import SweepAlignmentConfig
from mlsemreg_ros.core.alignment.sweep_alignment import MapGaussians, SweepAlignment
from mlsemreg_ros.core.features.deskew import SweepMotion
import numpy as np

#: The sweep alignment started ahead of the rules.
_POOL = threads.LazyPool('mlsemreg-sweep-ahead')
#: The caller waits at most this long (s) for the thread to run (:meth:`SweepAhead.start`).
START_TIMEOUT_S = 0.1


@dataclass(frozen=True)
class SweepInputs:
    """What a sweep alignment reads: the key a result started ahead is taken by."""

    raw: Any  # the PreprocessedScan whose sweep it aligns
    gaussians: MapGaussians
    pose: np.ndarray  # (4, 4)
    implied: SweepMotion | None
    config: SweepAlignmentConfig

    def matches(self, other: SweepInputs) -> bool:
        """Return whether both hold the same scan and Gaussians, equal settings, equal bits."""
        return (
            self.raw is other.raw
            and self.gaussians is other.gaussians
            and self.config == other.config
            and _bits(self.pose) == _bits(other.pose)
            and _twist_bits(self.implied) == _twist_bits(other.implied)
        )


def _bits(a: np.ndarray) -> Any:
    """Return the :func:`fingerprint` of ``a`` as float64 (NaN equal to itself)."""
    return fingerprint(np.asarray(a, dtype=np.float64))


def _twist_bits(twist: SweepMotion | None) -> Any:
    """Return None, or the bits of a twist's rate and velocity."""
    return None if twist is None else (_bits(twist.omega), _bits(twist.velocity))


@dataclass
class _Started:
    """A sweep alignment started ahead: its inputs and its result to come."""

    inputs: SweepInputs  # the pose copied
    result: Future[SweepAlignment]


class SweepAhead:
    """At most one sweep alignment started ahead, for the scan in process."""

    def __init__(self) -> None:
        self._started: _Started | None = None

    def start(self, inputs: SweepInputs, align: Callable[[np.ndarray], SweepAlignment]) -> bool:
        """
        Run ``align(inputs.pose)`` on the pool; :meth:`take` returns it for the same inputs.

        ``align``: the sweep alignment of ``inputs.raw`` against ``inputs.gaussians`` from a
        pose with the second start ``inputs.implied`` and ``inputs.config`` (the caller binds
        them). Returns whether it started (never with one worker).
        """
        self.drop()
        pose = np.array(inputs.pose, dtype=np.float64, copy=True)
        running = threading.Event()

        def run() -> SweepAlignment:
            running.set()
            return align(pose)

        future = _POOL.submit(run)
        if future is None:
            return False
        self._started = _Started(replace(inputs, pose=pose), future)
        # Hand the GIL over until the thread runs: else it waits for it while this thread
        # goes on in Python, up to the interpreter's switch interval (5 ms), and starts the
        # compiled loop only once the caller waits for its result (no overlap at all). It
        # holds the GIL from here to the compiled loop's call (under 0.1 ms), then the
        # caller goes on beside it.
        running.wait(START_TIMEOUT_S)  # bounded: the result is waited for when taken anyway
        return True

    def take(self, inputs: SweepInputs) -> SweepAlignment | None:
        """
        Return the result started for these inputs (None: none was, or for others).

        Waits for it. A result started for other inputs is waited for and dropped (its
        thread reads the same Gaussians), and the caller computes its own.
        """
        started, self._started = self._started, None
        if started is None:
            return None
        try:
            result = started.result.result()
        except Exception:  # the caller's own call raises it again
            return None
        return result if started.inputs.matches(inputs) else None

    def started_for(self, raw: Any) -> bool:
        """Whether a sweep alignment of ``raw`` was started and not taken yet."""
        return self._started is not None and self._started.inputs.raw is raw

    def drop(self) -> None:
        """Forget a result started ahead (waits for its thread: it reads the map's Gaussians)."""
        started, self._started = self._started, None
        if started is not None:
            try:
                started.result.result()
            except Exception:  # dropped anyway
                pass


def fingerprint(value: Any) -> Any:
    """
    Return a key equal for equal inputs: arrays and floats by their bits, objects by identity.

    Tuples, lists and dicts are keyed item by item; None, bools, ints and strings by value;
    anything else (a configuration) is the same object or not.
    """
    if isinstance(value, np.ndarray):
        return ('array', value.dtype.str, value.shape, value.tobytes())
    if isinstance(value, (float, np.floating)):
        return ('float', np.float64(value).tobytes())
    if isinstance(value, (tuple, list)):
        return (type(value).__name__, *(fingerprint(v) for v in value))
    if isinstance(value, dict):
        return ('dict', *((k, fingerprint(v)) for k, v in sorted(value.items())))
    if value is None or isinstance(value, (bool, int, str)):
        return value
    return ('object', id(value))


class Memo:
    """
    A pure function called early (beside the sweep alignment), its result kept for reuse.

    Called again with arguments of the same :func:`fingerprint` it returns the kept result
    (the same function of the same bits); with others it calls the function. The accepted
    scan's covariance calibration (0.3 ms) thus runs while the sweep alignment of its likely
    pose is on the second thread, and is used when the sweep alignment left the pose as it
    was (no bend, no start deskew).
    """

    def __init__(
        self, function: Callable[..., Any], args: tuple[Any, ...], kwargs: dict[str, Any]
    ) -> None:
        self.function = function
        self.key: Any = fingerprint((args, kwargs))  # the arguments are kept alive with it
        self._kept = (args, kwargs)
        try:
            self.result = function(*args, **kwargs)
        except Exception:  # computed again when asked (and raised then, if it still fails)
            self.key, self.result = None, None

    def __call__(self, args: tuple[Any, ...], kwargs: dict[str, Any]) -> Any:
        """Return ``function(*args, **kwargs)``: the kept result for the same arguments."""
        if self.key is not None and fingerprint((args, kwargs)) == self.key:
            return self.result
        return self.function(*args, **kwargs)

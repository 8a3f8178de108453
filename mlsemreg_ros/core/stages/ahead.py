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
The next search started ahead, on a second thread, while the gate before it runs.

On the refused path each search is followed by the gate (``core/stages/early_acceptance.py``),
which tries the end stages on the pool found so far; only when the gate does not adopt a
pose does the next search run. The next search (the swapped and far BEV searches, the
guided re-matching) reads only the two scans, their correspondences and the BEV search's
peaks, none of which the gate changes unless it adopts. With two workers (``threads`` 0
on two cores, or 2 or more), :class:`Ahead` starts that search on a thread of its own just
before the gate, and the search's stage takes the result when its turn comes
(:func:`ahead_or_now`); the gate and the search then share the two cores. When the gate
adopts a pose the search's result is dropped (its time is the price). Each search computes
exactly what it would compute in turn, so verdicts and poses are the same as with one
worker, where nothing runs ahead (docs/hard_pairs.md, "The refused path, ninth round").
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from mlsemreg_ros.core.results import VerificationResult
from mlsemreg_ros.core.stages.context import RegistrationContext, Stage
from mlsemreg_ros.core.threads import LazyPool, workers

Found = TypeVar('Found')

_AHEAD = LazyPool('search_ahead')


class Ahead:
    """Start ``stage``'s computation on a second thread when ``gate`` is about to run."""

    name = 'ahead'

    def __init__(
        self, stage: Stage, gate: Stage, compute: Callable[[RegistrationContext], object]
    ) -> None:
        """
        ``stage``: the search after ``gate``; ``compute``: the part the gate cannot change.

        ``compute(context)`` must read only what the gate leaves alone when it does not adopt
        (the scans, the correspondences, the config, ``context.searched``) and write nothing
        into ``context``; the stage takes its result with :func:`ahead_or_now`.
        """
        self.stage = stage
        self.gate = gate
        self.compute = compute

    def wanted(self, context: RegistrationContext) -> bool:
        """Two workers, and both the gate and the search after it would run now."""
        return (
            workers() > 1
            and self.stage.name not in context.done
            and self.gate.name not in context.done
            and self.stage.name not in context.ahead
            and self.gate.wanted(context)
            and self.stage.wanted(context)
        )

    def run(self, context: RegistrationContext) -> VerificationResult | None:
        """Start the search's computation; it joins nothing to the pool here."""
        future = _AHEAD.submit(lambda: self.compute(context))
        if future is not None:
            context.ahead[self.stage.name] = future
        return None


def ahead_or_now(
    context: RegistrationContext, name: str, compute: Callable[[RegistrationContext], Found]
) -> Found:
    """The result of ``compute(context)`` started ahead for the stage ``name``, or computed now."""
    future = context.ahead.pop(name, None)
    if future is None:
        return compute(context)
    return future.result()

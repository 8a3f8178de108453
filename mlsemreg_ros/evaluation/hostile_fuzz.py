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
The hostile-input run of ``mlsemreg fuzz-node``: every case through a running node.

:func:`fuzz_node_priors` drives the cases of :mod:`~mlsemreg_ros.evaluation.hostile_cases`
one after another (:func:`~mlsemreg_ros.evaluation.hostile_run.run_case`) from a probe
node, restarts the node after a crash, and returns a :class:`FuzzReport`. The node is
given as a :class:`NodeUnderTest` (its process is started by the command, from the ROS
layer above), its prior topics are :data:`IMU_TOPIC` and :data:`WHEEL_TOPIC`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
import json
from pathlib import Path
from typing import Any, Protocol

from mlsemreg_ros.evaluation.hostile_run import CaseResult

#: The prior topics the node must subscribe to (its imu_topic and wheel_odometry_topic).
IMU_TOPIC, WHEEL_TOPIC = 'imu/data', 'wheel/odometry'
#: Stamp of the first case (s); each case then takes 4 intervals and 1 s.
FIRST_STAMP_S = 1000.0


class FuzzInputError(ValueError):
    """The pairs to fuzz with cannot be read."""


class NodeUnderTest(Protocol):
    """The node process the cases are sent to."""

    def alive(self) -> bool:
        """Return whether the process still runs."""
        ...

    def restart(self) -> None:
        """Start the node again (after a crash)."""
        ...


@dataclass(frozen=True)
class FuzzPairs:
    """The scans of the good steps and how they are sent."""

    pairs: list[Any]  # pair files (or synthetic pairs) with pts_src/dst, labels, trans_gt
    interval_s: float  # between the scans of the moved step
    keyframe_twice: bool  # the keyframe sent twice (synthetic pairs), see run_case


@dataclass(frozen=True)
class FuzzOptions:
    """Which cases, how often, which hostile values."""

    repeat: int = 1  # runs of every case, each on the next pair
    only: str = ''  # run the cases whose name contains this
    seed: int = 34  # seed of the random hostile values


@dataclass
class FuzzReport:
    """The result of every case run, and the totals."""

    results: list[CaseResult] = field(default_factory=list)

    @property
    def crashes(self) -> int:
        """Return the cases in which the node died."""
        return sum(r.crashed for r in self.results)

    def total(self, name: str) -> int:
        """Return the sum of a count of :class:`CaseResult` (clouds, answered, good, ...)."""
        return sum(getattr(r, name) for r in self.results)

    @property
    def passed(self) -> bool:
        """Return True without a crash or a wrong pose, and with every cloud answered."""
        return (
            self.crashes == 0
            and self.total('wrong') == 0
            and self.total('answered') == self.total('clouds')
        )

    def table(self) -> Any:
        """Return the table by case."""
        from mlsemreg_ros.evaluation.tables import ResultTable

        rows = [
            [
                r.group,
                r.name,
                f'{r.answered}/{r.clouds}',
                f'{r.good_right}/{r.good}',
                str(r.wrong),
                'yes' if r.crashed else '',
                ', '.join(
                    f'{k}={v}'
                    for k, v in sorted(r.counts.items())
                    if '.' in k or k in ('prior_refused', 'deskew_refused')
                )[:120],
            ]
            for r in self.results
        ]
        headers = ('group', 'case', 'answered', 'good right', 'wrong', 'crash', 'counted')
        return ResultTable(headers, rows)

    def summary(self) -> str:
        """Return the line of the totals."""
        good, right = self.total('good'), self.total('good_right')
        return (
            f'{len(self.results)} cases: {self.crashes} crashes, {self.total("wrong")} wrong '
            f'poses published, {self.total("answered")}/{self.total("clouds")} clouds answered, '
            f'{right}/{good} good scans after hostile input published and right '
            f'({100.0 * right / max(good, 1):.1f} %)'
        )

    def write(self, folder: Path) -> Path:
        """Write ``cases.json`` (one object per case run) into ``folder``; return its path."""
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / 'cases.json'
        path.write_text(json.dumps([asdict(r) for r in self.results], indent=1))
        return path


def fuzz_pairs(folder: Path | None) -> FuzzPairs:
    """
    Return the pairs of a folder of pair files, or three synthetic street pairs.

    Pair files are sent as keyframe and moved scan only (``run_case``'s ``keyframe_twice``),
    1 s apart (~20 m: 20 m/s, within the wheel limit); synthetic pairs 0.1 s apart.
    """
    if folder is None:
        from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair

        return FuzzPairs([synthetic_pair(seed=s) for s in range(3)], 0.1, True)
    from mlsemreg_ros.datasets.pairs import list_pairs, load_pair

    files = list_pairs(folder)
    if not files:
        raise FuzzInputError(f'no pair files in {folder}')
    return FuzzPairs([load_pair(f) for f in files], 1.0, False)


def fuzz_node_priors(
    pairs: FuzzPairs, probe: Any, node: NodeUnderTest, options: FuzzOptions
) -> FuzzReport:
    """
    Run every case (``options.repeat`` times) through ``node`` from the ``probe`` node.

    Raises RuntimeError when the node does not subscribe to the prior topics.
    """
    from mlsemreg_ros.evaluation.hostile_cases import cases, Timeline
    from mlsemreg_ros.evaluation.hostile_run import PriorPublisher, run_case
    import numpy as np

    rng = np.random.default_rng(options.seed)
    interval = pairs.interval_s
    priors = PriorPublisher(probe.node, IMU_TOPIC, WHEEL_TOPIC)
    if not probe.wait_until(priors.connected, 60.0):
        raise RuntimeError('the node did not subscribe to the prior topics')
    report = FuzzReport()
    before: dict[str, int] = {}
    t0 = FIRST_STAMP_S
    count = len(cases(Timeline(t0, interval), rng))
    for run in range(options.repeat):
        for k in range(count):
            timeline = Timeline(t0, interval)
            case = cases(timeline, rng)[k]  # its messages at this case's times
            if options.only and options.only not in case.name:
                continue
            pair = pairs.pairs[(run * 7 + k) % len(pairs.pairs)]
            result, before = run_case(
                case,
                pair,
                timeline,
                probe,
                priors,
                node.alive,
                before,
                rng,
                keyframe_twice=pairs.keyframe_twice,
            )
            report.results.append(result)
            t0 += 4 * interval + 1.0
            if result.crashed:
                node.restart()
                before = {}
                probe.wait_until(priors.connected, 60.0)
    return report

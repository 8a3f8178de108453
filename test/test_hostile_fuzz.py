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
The loop of ``mlsemreg fuzz-node`` without a node: which cases, which pair, restarts, totals.

The node and the probe are stand-ins and ``run_case`` is replaced, so these tests check
:func:`~mlsemreg_ros.evaluation.hostile_fuzz.fuzz_node_priors` itself; the real node runs
the cases in test_node_hostile.py and through ``mlsemreg fuzz-node``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from mlsemreg_ros.evaluation import hostile_fuzz as fuzz
from mlsemreg_ros.evaluation import hostile_run
from mlsemreg_ros.evaluation.hostile_run import CaseResult
import pytest


class FakeNode:
    def __init__(self) -> None:
        self.starts = 1
        self.up = True

    def alive(self) -> bool:
        return self.up

    def restart(self) -> None:
        self.starts += 1
        self.up = True


class FakeProbe:
    node = None

    def __init__(self, connects: bool = True) -> None:
        self.connects = connects
        self.waits = 0

    def wait_until(self, condition: Any, timeout: float) -> bool:
        self.waits += 1
        return self.connects


class FakePriors:
    def __init__(self, node: Any, imu_topic: str, wheel_topic: str) -> None:
        assert (imu_topic, wheel_topic) == (fuzz.IMU_TOPIC, fuzz.WHEEL_TOPIC)

    def connected(self) -> bool:
        return True


@pytest.fixture
def calls(monkeypatch: pytest.MonkeyPatch) -> list[dict[str, Any]]:
    """Replace run_case: the node 'crashes' on the cases named 'stamp 0'."""
    seen: list[dict[str, Any]] = []

    def run_case(case, pair, timeline, probe, priors, alive, before, rng, keyframe_twice):
        seen.append(
            {
                'name': case.name,
                'pair': pair,
                't0': timeline.t0,
                'alive': alive(),
                'before': dict(before),
                'keyframe_twice': keyframe_twice,
            }
        )
        crashed = case.name == 'stamp 0'
        result = CaseResult(case.name, case.group, crashed, 3, 3 - crashed, 3, 3, 0, {'n': 1})
        return result, {'n': len(seen)}

    monkeypatch.setattr(hostile_run, 'run_case', run_case)
    monkeypatch.setattr(hostile_run, 'PriorPublisher', FakePriors)
    return seen


def test_only_repeat_and_the_pair_of_each_run(calls: list[dict[str, Any]]) -> None:
    pairs = fuzz.FuzzPairs(['a', 'b', 'c'], 0.1, True)
    node = FakeNode()
    report = fuzz.fuzz_node_priors(
        pairs, FakeProbe(), node, fuzz.FuzzOptions(repeat=2, only='quaternion of norm')
    )
    assert [c['name'] for c in calls] == ['one: quaternion of norm 2'] * 2
    k = 37  # its index in the case list
    assert [c['pair'] for c in calls] == [['a', 'b', 'c'][(run * 7 + k) % 3] for run in (0, 1)]
    assert calls[0]['t0'] == fuzz.FIRST_STAMP_S and calls[1]['t0'] == pytest.approx(1001.4)
    assert calls[1]['before'] == {'n': 1} and all(c['keyframe_twice'] for c in calls)
    assert node.starts == 1 and report.passed and report.total('good_right') == 6


def test_a_crash_restarts_the_node_and_counts(calls: list[dict[str, Any]], tmp_path: Path) -> None:
    node, probe = FakeNode(), FakeProbe()
    report = fuzz.fuzz_node_priors(
        fuzz.FuzzPairs(['p'], 1.0, False), probe, node, fuzz.FuzzOptions(only='stamp 0')
    )
    names = [r.name for r in report.results]  # the name contains 'stamp 0': imu, imu, wheel
    assert names == ['stamp 0', '10 among the stream with stamp 0', 'stamp 0']
    assert node.starts == 1 + 2 and probe.waits == 1 + 2
    assert [c['before'] for c in calls] == [{}, {}, {'n': 2}]  # restarted node: counts anew
    assert report.crashes == 2 and not report.passed
    assert report.summary().startswith('3 cases: 2 crashes, 0 wrong poses published, 7/9 clouds')
    assert len(report.table().rows) == 3
    written = json.loads(report.write(tmp_path / 'out').read_text())
    assert written[0]['name'] == 'stamp 0' and written[0]['crashed'] is True


def test_the_node_must_subscribe_to_the_priors(calls: list[dict[str, Any]]) -> None:
    with pytest.raises(RuntimeError, match='did not subscribe'):
        fuzz.fuzz_node_priors(
            fuzz.FuzzPairs(['p'], 1.0, False),
            FakeProbe(connects=False),
            FakeNode(),
            fuzz.FuzzOptions(),
        )
    assert calls == []


def test_fuzz_pairs(tmp_path: Path) -> None:
    with pytest.raises(fuzz.FuzzInputError, match='no pair files'):
        fuzz.fuzz_pairs(tmp_path)
    street = fuzz.fuzz_pairs(None)
    assert len(street.pairs) == 3 and street.interval_s == 0.1 and street.keyframe_twice

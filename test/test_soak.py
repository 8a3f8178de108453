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

"""mlsemreg soak on a short loop: the node process answers every scan, its RSS is read."""

from __future__ import annotations

import os
from pathlib import Path

from mlsemreg_ros.evaluation.soak import growth_mb, rss_mb, SoakSample
from mlsemreg_ros.tools import simulate, soak
import pytest
from ros_domains import domain_id

os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
pytest.importorskip('rclpy', reason='rclpy (ROS 2 Jazzy wheels) not installed')
pytestmark = pytest.mark.slow  # a node process


def test_rss_of_this_process_and_growth_after_the_warm_up() -> None:
    assert 10.0 < rss_mb(os.getpid()) < 1e6
    assert rss_mb(2**22 + 12345) != rss_mb(2**22 + 12345)  # no such process: NaN
    samples = [SoakSample(0, 100.0, 0), SoakSample(10, 140.0, 1), SoakSample(20, 141.5, 2)]
    assert growth_mb(samples, 10) == pytest.approx(1.5)
    noisy = [SoakSample(k, 200.0 + (5.0 if k % 20 else -5.0), 0) for k in range(0, 420, 10)]
    assert abs(growth_mb(noisy, 20)) < 1.0  # 10 MiB ups and downs, no trend
    assert abs(noisy[-1].rss_mb - noisy[2].rss_mb) == 10.0  # end minus start would say 10
    assert growth_mb(samples, 30) != growth_mb(samples, 30)  # nothing after the warm-up


def test_soak_loops_a_bag_through_the_node(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = tmp_path / 'sim'
    assert (
        simulate.main(
            [str(bag), '--frames', '4', '--seed', '2', '--azimuth-steps', '512', '--quiet']
        )
        == 0
    )
    assert (
        soak.main(
            [
                str(bag),
                '--frames',
                '10',
                '--every',
                '5',
                '--warm-up',
                '5',
                '--domain-id',
                str(domain_id('soak')),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert 'RSS growth after 5 scans' in out and '(10 scans of sim, 4 per loop)' in out

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
"""The first-pair searches' shared checks (test_start_search.py, test_ring_start_search.py)."""

from collections.abc import Callable, Iterable
from types import SimpleNamespace
from typing import Any

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry import Odometry
from mlsemreg_ros.core.odometry.narrow_view import View
from mlsemreg_ros.core.odometry.steps import Decision
from mlsemreg_ros.core.pipeline import Registration
import numpy as np

#: The keyframe's pose and stamp the views are measured from.
KEYFRAME = (np.eye(4), 1_000_000_000)


def view_at(span_deg: float, *stamps_ns: int) -> View:
    """Return a view of ``span_deg`` that saw the scans at ``stamps_ns`` after the keyframe."""
    view = View(span_deg=span_deg)
    for stamp_ns in stamps_ns:
        view.since(KEYFRAME, stamp_ns)
    return view


def assert_untouched(
    search: Callable[..., Decision],
    cases: Iterable[tuple[View, object | None, RegistrationConfig]],
) -> None:
    """
    Assert ``search`` gives a refused decision back untouched in each case.

    ``cases``: (view, prediction, config); nothing else is asked of the odometry.
    """
    refused = Decision(source='', reason='refused')
    for view, prediction, cfg in cases:
        odometry = SimpleNamespace(
            config=cfg, tracker=SimpleNamespace(trust=SimpleNamespace(view=view))
        )
        assert search(odometry, 2_000_000_000, prediction, None, refused, {}) is refused


def assert_first_pair_found(
    first: Any, last: Any, settings: dict[str, Any], overlap_key: str, overlap: float, said: str
) -> None:
    """
    Assert the first pair is refused with the search off and found with it on.

    ``settings`` and ``overlap_key`` (the search's overlap bar, 0: off) configure the
    odometry; the found pose is within 0.6 m / 5 deg of the truth and its reason says
    ``said``.
    """
    truth = np.linalg.solve(first.pose, last.pose)
    steps = {}
    for name, bar in (('before', 0.0), ('after', overlap)):
        config = RegistrationConfig().replace({**settings, overlap_key: bar})
        odometry = Odometry(Registration(config))
        for scan in (first, last):
            steps[name] = odometry.process(
                scan.xyz, scan.labels, scan.stamp_ns, point_times=scan.point_times
            )
    assert not steps['before'].accepted  # the code before: the global registration refuses
    after = steps['after']
    assert after.accepted and said in after.reason, after.reason
    error = np.linalg.solve(truth, after.relative)
    assert np.linalg.norm(after.relative[:3, 3] - truth[:3, 3]) < 0.6
    assert np.degrees(np.arccos(np.clip((np.trace(error[:3, :3]) - 1) / 2, -1, 1))) < 5.0

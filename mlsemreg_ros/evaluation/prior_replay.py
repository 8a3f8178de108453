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
The replay of an odometry fed with a bag's motion-prior topics (``docs/field_prior.md``).

:class:`PriorFedEstimator` wraps the odometry's estimator: before each scan it hands the
motion model the IMU and wheel messages stamped up to the end of the scan's sweep
(:meth:`~mlsemreg_ros.datasets.prior_topics.PriorTopics.feed_until`), then steps it.
"""

from __future__ import annotations

from typing import Any

from mlsemreg_ros.datasets.prior_topics import PriorTopics, sweep_end_ns
from mlsemreg_ros.datasets.source import Scan
from mlsemreg_ros.evaluation.records import FrameEstimate


class PriorFedEstimator:
    """An odometry estimator whose motion model hears the prior topics first."""

    def __init__(self, estimator: Any, topics: PriorTopics) -> None:
        """Wrap ``estimator`` (with an ``odometry``) and feed it ``topics``."""
        model = estimator.odometry.motion_model
        if topics and not hasattr(model, 'add_imu'):
            raise ValueError(
                f'the motion model {type(model).__name__} takes no prior messages '
                '(motion_prior.source is none?)'
            )
        self.estimator = estimator
        self.topics = topics
        self.method = estimator.method
        self.progress_label = estimator.progress_label

    @property
    def odometry(self) -> Any:
        """Return the wrapped odometry."""
        return self.estimator.odometry

    def step(self, scan: Scan) -> FrameEstimate:
        """Feed the messages up to the sweep end, then process the scan."""
        model = self.estimator.odometry.motion_model
        self.topics.feed_until(model, sweep_end_ns(scan.stamp_ns, scan.point_times))
        return self.estimator.step(scan)

    def prediction_sources(self) -> dict[str, int]:
        """Return how many predictions each source made ('imu', 'wheel', ...)."""
        return dict(getattr(self.estimator.odometry.motion_model, 'counts', {}))

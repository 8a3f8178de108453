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


def prediction_errors(
    bag: str,
    source: str,
    stride: int = 1,
    imu_topic: str = '/imu/data',
    wheel_topic: str = '/wheel/odometry',
    gt_topic: str = '',
) -> dict[str, float]:
    """
    Score a motion model's predictions on a bag's ground truth (no registration).

    The model (``motion_prior.source`` = ``source``; ``none`` is constant velocity) is fed
    the bag's prior topics and updated with the true poses (``gt_topic``, default the
    bag's ground truth, one per scan) of every ``stride``-th scan; each
    prediction from the third scan on is compared with the true pose. Returns the mean, 95th
    percentile and maximum translation (m) and rotation (deg) errors, and the count.
    """
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.odometry.motion_model import make_motion_model
    from mlsemreg_ros.core.odometry.prior_model import motion_model_name
    from mlsemreg_ros.core.rigid import invert_transform, rotation_angle_deg
    from mlsemreg_ros.datasets.bag import GT_TOPIC, read_wheel_odometry
    from mlsemreg_ros.datasets.prior_topics import read_prior_topics
    import numpy as np

    gt_topic = gt_topic or GT_TOPIC
    cfg = RegistrationConfig()
    cfg.motion_prior.source = source
    model = make_motion_model(cfg, motion_model_name(cfg))
    topics = read_prior_topics(bag, imu_topic, wheel_topic) if source != 'none' else None
    truth = read_wheel_odometry(bag, gt_topic)  # any nav_msgs/Odometry topic
    scans = list(zip(truth.stamps_ns[::stride], truth.poses[::stride], strict=True))
    first = invert_transform(scans[0][1])
    errors = []
    for k, (stamp, pose) in enumerate(scans):
        pose = first @ pose
        if topics is not None:
            topics.feed_until(model, stamp)
        prediction = model.predict(stamp)
        if k >= 2 and prediction is not None:
            error = invert_transform(pose) @ prediction.T_odom_current
            errors.append((np.linalg.norm(error[:3, 3]), rotation_angle_deg(error)))
        model.update(pose, stamp)
    t, r = np.array(errors).reshape(-1, 2).T
    return {
        'n': len(errors),
        't_mean_m': float(t.mean()),
        't_p95_m': float(np.percentile(t, 95)),
        't_max_m': float(t.max()),
        'r_mean_deg': float(r.mean()),
        'r_p95_deg': float(np.percentile(r, 95)),
        'r_max_deg': float(r.max()),
    }

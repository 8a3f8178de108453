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
Replay a bag offline through the node's odometry, score it and write the results folder.

The logic of ``mlsemreg eval-bag``, callable from Python: :func:`evaluate_bag` opens the
bag (mcap or sqlite3, or a SemanticKITTI folder), runs every kept scan through
:class:`~mlsemreg_ros.core.odometry.Odometry` (the node's code path) by
:func:`~mlsemreg_ros.evaluation.replay.replay`, runs the chosen peers on the same scans,
and writes the folder of :mod:`mlsemreg_ros.evaluation.reports`;
:func:`print_bag_evaluation` prints its tables.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TYPE_CHECKING

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.evaluation.peer_runs import PeerResults
    from mlsemreg_ros.evaluation.records import EvalRun
    from mlsemreg_ros.evaluation.settings import EvaluationConfig


class BagInputError(ValueError):
    """The bag, its topics or the prior topics cannot be read as asked."""


class NoScansRead(RuntimeError):
    """The replay read no scan."""


@dataclass(frozen=True)
class BagTopics:
    """Where a rosbag2's data is (ignored for a SemanticKITTI folder)."""

    label_field: str  # the node's label_field parameter
    points_topic: str | None = None  # None: the only PointCloud2 topic
    gt_topic: str = 'auto'  # auto: /ground_truth/odometry if present; none: ignore
    imu_topic: str = ''  # sensor_msgs/Imu fed to the motion prior ('': none)
    wheel_topic: str = ''  # nav_msgs/Odometry fed to the motion prior ('': none)


@dataclass(frozen=True)
class BagEvalOptions:
    """Which scans, which truth, which peers, what to write."""

    stride: int = 1  # register scan k against k - stride
    max_frames: int | None = None  # stop after this many kept scans
    gt_poses: Path | None = None  # KITTI poses file, one line per bag scan (overrides the bag)
    gt_calib: Path | None = None  # KITTI calib.txt: gt_poses from camera to LiDAR frame
    plot_frame: int | None = None  # bag index of the correspondence plot (None: middle)
    plots: bool = True  # write the PNG plots
    baselines: tuple[str, ...] = ()  # odometry peers run on the same scans (peer_runs)
    drop_scans: float = 0.0  # seeded share of scans replaced by degenerate ones
    drop_seed: int = 0
    progress: bool = True
    argv: tuple[str, ...] = ()  # the invocation, recorded in details.json


@dataclass
class BagEvaluation:
    """What :func:`evaluate_bag` measured and where it wrote it."""

    run: EvalRun
    summary: dict[str, Any]  # summary.json
    details: dict[str, Any]  # details.json
    peers: PeerResults
    deskewed_scans: dict[str, int] = field(default_factory=dict)  # by method label
    output: Path = Path()
    dropped: bool = False  # scans were replaced (the recovery table applies)


def evaluate_bag(
    bag: Path,
    core: RegistrationConfig,
    bounds: EvaluationConfig,
    topics: BagTopics,
    options: BagEvalOptions,
    output: Path | None = None,
    results_root: Path = Path('results'),
) -> BagEvaluation:
    """
    Replay ``bag`` through our odometry (and the peers), score it and write the results.

    ``output`` None: a new ``results_root/eval_bag/<time>_<bag>`` with a ``latest`` link.
    Raises :class:`~mlsemreg_ros.evaluation.peer_runs.PeerUnavailable`,
    :class:`BagInputError` and :class:`NoScansRead`.
    """
    from mlsemreg_ros.core.odometry import Odometry
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.evaluation import drop_scans as drop
    from mlsemreg_ros.evaluation import peer_runs, reports
    from mlsemreg_ros.evaluation.estimators import OdometryEstimator
    from mlsemreg_ros.evaluation.replay import replay, ReplayOptions
    from mlsemreg_ros.evaluation.scoring import run_details, summarize_run

    peer_runs.require_peers(list(options.baselines))
    open_source = _source_opener(bag, core, topics, options.gt_poses is not None)
    truth = _truth(options.gt_poses, options.gt_calib)
    replay_options = ReplayOptions(
        options.stride, options.max_frames, truth, options.plot_frame, options.progress
    )
    ours = OdometryEstimator(Odometry(Registration(core)))
    estimator = ours
    if topics.imu_topic or topics.wheel_topic:
        estimator = _fed_with_prior(bag, ours, topics.imu_topic, topics.wheel_topic)
    source = open_source()
    if options.drop_scans:
        source = drop.DroppedScans(source, options.drop_scans, options.drop_seed)
    try:
        run = replay(source, estimator, bounds, replay_options)
    finally:
        source.close()
    if not run.records:
        raise NoScansRead('no scans read')
    if options.drop_scans:
        summary = drop.summarize_with_drops(run, source.degenerate_indices)
    else:
        summary = summarize_run(run)
    details = run_details(
        run,
        bag=str(bag),
        stride=options.stride,
        max_frames=options.max_frames,
        argv=list(options.argv),
        deskewed_scans=ours.deskewed_scans,
    )
    if hasattr(estimator, 'prediction_sources'):
        details['prediction_sources'] = estimator.prediction_sources()
    out = output or reports.default_output(results_root, 'eval_bag', run.name)
    peers = peer_runs.run_odometry_peers(
        open_source,
        list(options.baselines),
        bounds,
        ReplayOptions(options.stride, options.max_frames, truth, progress=options.progress),
        out,
        bag=str(bag),
        stride=options.stride,
    )
    reports.write_results(
        out,
        run,
        summary,
        details,
        reports.effective_config(core),
        bounds,
        plots=options.plots,
        extra=peers.poses,
    )
    if output is None:
        reports.link_latest(out)
    deskewed = {run.method: ours.deskewed_scans, **peers.deskewed_scans}
    return BagEvaluation(run, summary, details, peers, deskewed, out, bool(options.drop_scans))


def print_bag_evaluation(result: BagEvaluation) -> None:
    """Print the summary table (ours and the peers), recovery, deskew and wrong-pose lines."""
    from mlsemreg_ros.evaluation import drop_scans as drop
    from mlsemreg_ros.evaluation import tables

    run = result.run
    tables.print_table(
        tables.sequence_summary_table(result.summary, run.method, result.peers.summaries)
    )
    if result.dropped:
        tables.print_table(drop.recovery_table(result.summary))
    tables.print_text(
        'deskewed scans (per-point times): '
        + ', '.join(f'{name} {n}/{len(run.records)}' for name, n in result.deskewed_scans.items())
    )
    wrong = {run.method: result.details, **result.peers.details}
    tables.print_text(
        'wrong poses published (accepted, outside the success bounds): '
        + ', '.join(f'{name} {d["n_accepted"] - d["n_success"]}' for name, d in wrong.items())
    )
    tables.print_text(f'results: {result.output}')


def _source_opener(
    bag: Path, core: RegistrationConfig, topics: BagTopics, truth_from_file: bool
) -> Callable[[], Any]:
    """Return a function that opens a fresh scan source of ``bag`` (BagInputError if not)."""
    from mlsemreg_ros.datasets.factory import is_rosbag2, open_scan_source
    from mlsemreg_ros.datasets.source import SourceError

    kwargs: dict[str, Any] = {}
    if is_rosbag2(bag):
        kwargs = {
            'points_topic': topics.points_topic,
            'label_field': topics.label_field,
            'gt_topic': None if topics.gt_topic == 'none' or truth_from_file else topics.gt_topic,
            'time_field': core.preprocess.time_field,
            'time_unit': core.preprocess.time_unit,
        }

    def open_source() -> Any:
        try:
            return open_scan_source(bag, **kwargs)
        except SourceError as error:
            raise BagInputError(str(error)) from None

    return open_source


def _truth(gt_poses: Path | None, gt_calib: Path | None) -> Any:
    """Return the (F, 4, 4) LiDAR poses of a KITTI poses file, or None without one."""
    from mlsemreg_ros.datasets.pose_files import (
        camera_to_lidar_poses,
        read_kitti_calib,
        read_kitti_poses,
    )

    if gt_poses is None:
        return None
    truth = read_kitti_poses(gt_poses)
    if gt_calib is not None:
        truth = camera_to_lidar_poses(truth, read_kitti_calib(gt_calib)['Tr'])
    return truth


def _fed_with_prior(bag: Path, estimator: Any, imu_topic: str, wheel_topic: str) -> Any:
    """Wrap ``estimator`` so its motion model hears the bag's prior topics first."""
    from mlsemreg_ros.datasets.factory import is_rosbag2
    from mlsemreg_ros.datasets.prior_topics import read_prior_topics
    from mlsemreg_ros.datasets.source import SourceError
    from mlsemreg_ros.evaluation.prior_replay import PriorFedEstimator

    if not is_rosbag2(bag):
        raise BagInputError('--imu-topic / --wheel-topic need a rosbag2')
    try:
        return PriorFedEstimator(estimator, read_prior_topics(bag, imu_topic, wheel_topic))
    except (SourceError, ValueError) as error:
        raise BagInputError(str(error)) from None

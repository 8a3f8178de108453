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
``mlsemreg eval-bag BAG``: replay a bag offline through the node's odometry and score it.

No ROS runtime: the bag is read with ``rosbags`` (mcap or sqlite3; a SemanticKITTI folder
works too) and every scan goes through :class:`mlsemreg_ros.core.odometry.Odometry` (the
node's code path) by :func:`mlsemreg_ros.evaluation.replay.replay`. ``--stride S`` keeps
every S-th scan, so scan k is registered against scan k - S (keyframe policy
every_frame). The results folder is described in :mod:`mlsemreg_ros.evaluation.reports`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

from mlsemreg_ros.evaluation.peer_runs import OdometryPeer
from mlsemreg_ros.ros.node_config import NodeConfig
from mlsemreg_ros.tools.common import (
    alias,
    CommandError,
    ConfigOption,
    DATA,
    invocation_argv,
    LabelsOption,
    OUTPUT,
    QuietOption,
    SetOption,
    settings,
    with_labels,
)
import typer

HELP = (
    "Replay a bag (mcap or sqlite3) or SemanticKITTI folder offline through the node's "
    'registration and keyframe policy; write metrics, trajectories and plots.'
)


#: The node parameter this option mirrors (its default and description).
_LABEL_FIELD = NodeConfig.field_of('label_field')


def eval_bag(
    context: typer.Context,
    bag: Annotated[
        Path,
        typer.Argument(
            exists=True,
            help='rosbag2 directory / .mcap / .db3, or a SemanticKITTI sequence folder',
        ),
    ],
    output: Annotated[
        Path | None,
        typer.Option(
            '-o',
            '--output',
            help='results folder (default: RESULTS_ROOT/eval_bag/<time>_<bag>)',
            rich_help_panel=OUTPUT,
        ),
    ] = None,
    results_root: Annotated[
        Path, typer.Option(help='where default results folders go', rich_help_panel=OUTPUT)
    ] = Path('results'),
    points_topic: Annotated[
        str | None,
        typer.Option(help='PointCloud2 topic (default: the only one)', rich_help_panel=DATA),
    ] = None,
    label_field: Annotated[
        str, typer.Option(help=_LABEL_FIELD.metadata['description'], rich_help_panel=DATA)
    ] = _LABEL_FIELD.default,
    gt_topic: Annotated[
        str,
        typer.Option(
            help='ground-truth Odometry/PoseStamped topic; auto: /ground_truth/odometry if '
            'present; none: ignore',
            rich_help_panel=DATA,
        ),
    ] = 'auto',
    gt_poses: Annotated[
        Path | None,
        typer.Option(
            exists=True,
            dir_okay=False,
            help='KITTI poses file, one line per bag scan (overrides the bag ground truth)',
            rich_help_panel=DATA,
        ),
    ] = None,
    gt_calib: Annotated[
        Path | None,
        typer.Option(
            exists=True,
            dir_okay=False,
            help='KITTI calib.txt: convert --gt-poses from camera to LiDAR frame with Tr',
            rich_help_panel=DATA,
        ),
    ] = None,
    stride: Annotated[
        int, typer.Option(min=1, help='register scan k against k - S', rich_help_panel=DATA)
    ] = 1,
    max_frames: Annotated[
        int | None,
        typer.Option(min=1, help='stop after this many (strided) scans', rich_help_panel=DATA),
    ] = None,
    config: ConfigOption = None,
    labels: LabelsOption = None,
    overrides: SetOption = None,
    plot_frame: Annotated[
        int | None,
        typer.Option(
            min=0,
            help='bag index of the correspondence plot (default: middle of the run)',
            rich_help_panel=OUTPUT,
        ),
    ] = None,
    no_plots: Annotated[
        bool, typer.Option('--no-plots', help='skip the PNG plots', rich_help_panel=OUTPUT)
    ] = False,
    fail_below: Annotated[
        float | None,
        typer.Option(
            metavar='RR',
            min=0.0,
            max=100.0,
            help='exit with status 1 if the registration recall (%) is below RR',
            rich_help_panel=OUTPUT,
        ),
    ] = None,
    quiet: QuietOption = False,
    imu_topic: Annotated[
        str,
        typer.Option(
            help="sensor_msgs/Imu topic fed to the motion prior ('': none; docs/field_prior.md)",
            rich_help_panel=DATA,
        ),
    ] = '',
    wheel_topic: Annotated[
        str,
        typer.Option(
            help="nav_msgs/Odometry wheel topic fed to the motion prior ('': none)",
            rich_help_panel=DATA,
        ),
    ] = '',
    baseline: Annotated[
        list[OdometryPeer] | None,
        typer.Option(
            help='also run this peer on the same scans and compare (results in OUTPUT/<peer>/); '
            'repeatable',
        ),
    ] = None,
    drop_scans: Annotated[
        float,
        typer.Option(
            metavar='P',
            min=0.0,
            max=1.0,
            help='replace a seeded share P of the scans by degenerate ones (3 points) and count '
            'the recovery (docs/evaluation.md)',
            rich_help_panel=DATA,
        ),
    ] = 0.0,
    drop_seed: Annotated[int, typer.Option(help='seed of --drop-scans', rich_help_panel=DATA)] = 0,
) -> int:
    """Replay a bag offline through the node's odometry and score it (alias mlsemreg-eval-bag)."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.odometry import Odometry
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.datasets.factory import is_rosbag2, open_scan_source
    from mlsemreg_ros.datasets.pose_files import (
        camera_to_lidar_poses,
        read_kitti_calib,
        read_kitti_poses,
    )
    from mlsemreg_ros.datasets.source import SourceError
    from mlsemreg_ros.evaluation import drop_scans as drop
    from mlsemreg_ros.evaluation import peer_runs, reports, tables
    from mlsemreg_ros.evaluation.estimators import OdometryEstimator
    from mlsemreg_ros.evaluation.replay import replay, ReplayOptions
    from mlsemreg_ros.evaluation.scoring import run_details, summarize_run
    from mlsemreg_ros.evaluation.settings import EvaluationSettings

    peer_names = [peer.value for peer in baseline or []]
    try:
        peer_runs.require_peers(peer_names)
    except peer_runs.PeerUnavailable as error:
        raise CommandError(str(error), 2) from None
    core, evaluation = settings(
        (RegistrationConfig, EvaluationSettings), config, with_labels(overrides, labels)
    )
    bounds = evaluation.evaluation
    kwargs: dict[str, Any] = {}
    if is_rosbag2(bag):
        kwargs = {
            'points_topic': points_topic,
            'label_field': label_field,
            'gt_topic': None if gt_topic == 'none' or gt_poses else gt_topic,
            'time_field': core.preprocess.time_field,
            'time_unit': core.preprocess.time_unit,
        }

    def open_source() -> Any:
        try:
            return open_scan_source(bag, **kwargs)
        except SourceError as error:
            raise CommandError(str(error), 2) from None

    truth = None
    if gt_poses is not None:
        truth = read_kitti_poses(gt_poses)
        if gt_calib is not None:
            truth = camera_to_lidar_poses(truth, read_kitti_calib(gt_calib)['Tr'])
    options = ReplayOptions(stride, max_frames, truth, plot_frame, progress=not quiet)
    ours = OdometryEstimator(Odometry(Registration(core)))
    estimator = ours
    if imu_topic or wheel_topic:
        estimator = _fed_with_prior(bag, ours, imu_topic, wheel_topic)
    source = open_source()
    if drop_scans:
        source = drop.DroppedScans(source, drop_scans, drop_seed)
    try:
        run_ = replay(source, estimator, bounds, options)
    finally:
        source.close()
    if not run_.records:
        raise CommandError('no scans read')
    if drop_scans:
        summary = drop.summarize_with_drops(run_, source.degenerate_indices)
    else:
        summary = summarize_run(run_)
    deskewed = {run_.method: ours.deskewed_scans}
    details = run_details(
        run_,
        bag=str(bag),
        stride=stride,
        max_frames=max_frames,
        argv=invocation_argv(context),
        deskewed_scans=ours.deskewed_scans,
    )
    if hasattr(estimator, 'prediction_sources'):
        details['prediction_sources'] = estimator.prediction_sources()
    out = output or reports.default_output(results_root, 'eval_bag', run_.name)
    peers = peer_runs.run_odometry_peers(
        open_source,
        peer_names,
        bounds,
        ReplayOptions(stride, max_frames, truth, progress=not quiet),
        out,
        bag=str(bag),
        stride=stride,
    )
    others, extra = peers.summaries, peers.poses
    deskewed.update(peers.deskewed_scans)
    reports.write_results(
        out,
        run_,
        summary,
        details,
        reports.effective_config(core),
        bounds,
        plots=not no_plots,
        extra=extra,
    )
    if output is None:
        reports.link_latest(out)
    tables.print_table(tables.sequence_summary_table(summary, run_.method, others))
    if drop_scans:
        tables.print_table(drop.recovery_table(summary))
    tables.print_text(
        'deskewed scans (per-point times): '
        + ', '.join(f'{name} {n}/{len(run_.records)}' for name, n in deskewed.items())
    )
    wrong = {run_.method: details, **peers.details}
    tables.print_text(
        'wrong poses published (accepted, outside the success bounds): '
        + ', '.join(f'{name} {d["n_accepted"] - d["n_success"]}' for name, d in wrong.items())
    )
    tables.print_text(f'results: {out}')
    rr = summary['registration_recall_pct']
    if fail_below is not None and (rr is None or rr < fail_below):
        raise CommandError(f'registration recall {rr} % < {fail_below} %')
    return 0


def _fed_with_prior(bag: Path, estimator: Any, imu_topic: str, wheel_topic: str) -> Any:
    """Wrap ``estimator`` so its motion model hears the bag's prior topics first."""
    from mlsemreg_ros.datasets.factory import is_rosbag2
    from mlsemreg_ros.datasets.prior_topics import read_prior_topics
    from mlsemreg_ros.datasets.source import SourceError
    from mlsemreg_ros.evaluation.prior_replay import PriorFedEstimator

    if not is_rosbag2(bag):
        raise CommandError('--imu-topic / --wheel-topic need a rosbag2', 2)
    try:
        return PriorFedEstimator(estimator, read_prior_topics(bag, imu_topic, wheel_topic))
    except (SourceError, ValueError) as error:
        raise CommandError(str(error), 2) from None


main = alias(eval_bag, HELP, 'mlsemreg-eval-bag')

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
node's code path). ``--stride S`` keeps every S-th scan, so scan k is registered against
scan k - S (keyframe policy every_frame). The run is
:func:`mlsemreg_ros.evaluation.bag_run.evaluate_bag`; this module is its command line. The
results folder is described in :mod:`mlsemreg_ros.evaluation.reports`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from mlsemreg_ros.evaluation.peer_runs import OdometryPeer
from mlsemreg_ros.ros.node_config import NodeConfig
from mlsemreg_ros.tools.common import (
    alias,
    CommandError,
    ConfigOption,
    DATA,
    invocation_argv,
    LabelsOption,
    options_from,
    OUTPUT,
    QuietOption,
    replay_options,
    require_peers,
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


BagArgument = Annotated[
    Path,
    typer.Argument(
        exists=True,
        help='rosbag2 directory / .mcap / .db3, or a SemanticKITTI sequence folder',
    ),
]
OutputOption = Annotated[
    Path | None,
    typer.Option(
        '-o',
        '--output',
        help='results folder (default: RESULTS_ROOT/eval_bag/<time>_<bag>)',
        rich_help_panel=OUTPUT,
    ),
]
ResultsRootOption = Annotated[
    Path, typer.Option(help='where default results folders go', rich_help_panel=OUTPUT)
]
PointsTopicOption = Annotated[
    str | None,
    typer.Option(help='PointCloud2 topic (default: the only one)', rich_help_panel=DATA),
]
LabelFieldOption = Annotated[
    str, typer.Option(help=_LABEL_FIELD.metadata['description'], rich_help_panel=DATA)
]
GtTopicOption = Annotated[
    str,
    typer.Option(
        help='ground-truth Odometry/PoseStamped topic; auto: /ground_truth/odometry if '
        'present; none: ignore',
        rich_help_panel=DATA,
    ),
]
GtPosesOption = Annotated[
    Path | None,
    typer.Option(
        exists=True,
        dir_okay=False,
        help='KITTI poses file, one line per bag scan (overrides the bag ground truth)',
        rich_help_panel=DATA,
    ),
]
GtCalibOption = Annotated[
    Path | None,
    typer.Option(
        exists=True,
        dir_okay=False,
        help='KITTI calib.txt: convert --gt-poses from camera to LiDAR frame with Tr',
        rich_help_panel=DATA,
    ),
]
StrideOption, MaxFramesOption = replay_options()  # shared with tune
PlotFrameOption = Annotated[
    int | None,
    typer.Option(
        min=0,
        help='bag index of the correspondence plot (default: middle of the run)',
        rich_help_panel=OUTPUT,
    ),
]
NoPlotsOption = Annotated[
    bool, typer.Option('--no-plots', help='skip the PNG plots', rich_help_panel=OUTPUT)
]
FailBelowOption = Annotated[
    float | None,
    typer.Option(
        metavar='RR',
        min=0.0,
        max=100.0,
        help='exit with status 1 if the registration recall (%) is below RR',
        rich_help_panel=OUTPUT,
    ),
]
ImuTopicOption = Annotated[
    str,
    typer.Option(
        help="sensor_msgs/Imu topic fed to the motion prior ('': none; docs/field_prior.md)",
        rich_help_panel=DATA,
    ),
]
WheelTopicOption = Annotated[
    str,
    typer.Option(
        help="nav_msgs/Odometry wheel topic fed to the motion prior ('': none)",
        rich_help_panel=DATA,
    ),
]
BaselineOption = Annotated[
    list[OdometryPeer] | None,
    typer.Option(
        help='also run this peer on the same scans and compare (results in OUTPUT/<peer>/); '
        'repeatable',
    ),
]
DropScansOption = Annotated[
    float,
    typer.Option(
        metavar='P',
        min=0.0,
        max=1.0,
        help='replace a seeded share P of the scans by degenerate ones (3 points) and count '
        'the recovery (docs/evaluation.md)',
        rich_help_panel=DATA,
    ),
]
DropSeedOption = Annotated[int, typer.Option(help='seed of --drop-scans', rich_help_panel=DATA)]


def eval_bag(
    context: typer.Context,
    bag: BagArgument,
    output: OutputOption = None,
    results_root: ResultsRootOption = Path('results'),
    points_topic: PointsTopicOption = None,
    label_field: LabelFieldOption = _LABEL_FIELD.default,
    gt_topic: GtTopicOption = 'auto',
    gt_poses: GtPosesOption = None,
    gt_calib: GtCalibOption = None,
    stride: StrideOption = 1,
    max_frames: MaxFramesOption = None,
    config: ConfigOption = None,
    labels: LabelsOption = None,
    overrides: SetOption = None,
    plot_frame: PlotFrameOption = None,
    no_plots: NoPlotsOption = False,
    fail_below: FailBelowOption = None,
    quiet: QuietOption = False,
    imu_topic: ImuTopicOption = '',
    wheel_topic: WheelTopicOption = '',
    baseline: BaselineOption = None,
    drop_scans: DropScansOption = 0.0,
    drop_seed: DropSeedOption = 0,
) -> int:
    """Replay a bag offline through the node's odometry and score it (alias mlsemreg-eval-bag)."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.evaluation import bag_run
    from mlsemreg_ros.evaluation.peer_runs import PeerUnavailable
    from mlsemreg_ros.evaluation.settings import EvaluationSettings

    peer_names = tuple(peer.value for peer in baseline or [])
    require_peers(peer_names)
    core, evaluation = settings(
        (RegistrationConfig, EvaluationSettings), config, with_labels(overrides, labels)
    )
    topics = options_from(context, bag_run.BagTopics)
    options = options_from(
        context, bag_run.BagEvalOptions, plots=not no_plots, baselines=peer_names,
        progress=not quiet, argv=tuple(invocation_argv(context)),
    )  # fmt: skip
    try:
        result = bag_run.evaluate_bag(
            bag, core, evaluation.evaluation, topics, options, output, results_root
        )
    except (bag_run.BagInputError, PeerUnavailable) as error:
        raise CommandError(str(error), 2) from None
    except bag_run.NoScansRead as error:
        raise CommandError(str(error)) from None
    bag_run.print_bag_evaluation(result)
    rr = result.summary['registration_recall_pct']
    if fail_below is not None and (rr is None or rr < fail_below):
        raise CommandError(f'registration recall {rr} % < {fail_below} %')
    return 0


main = alias(eval_bag, HELP, 'mlsemreg-eval-bag')

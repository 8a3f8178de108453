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
``mlsemreg play BAG``: publish a bag's topics with rclpy (a stand-in for ``ros2 bag play``).

The player is :class:`mlsemreg_ros.ros.player.Player`, run by
:func:`mlsemreg_ros.ros.play_bag.play_bag`; this module is its command line.
"""

from __future__ import annotations

from pathlib import Path
import sys
from typing import Annotated

from mlsemreg_ros.tools.common import options_from, run, single_command_app
import typer

HELP = "Publish a bag's topics with rclpy at the recorded rate (stand-in for ros2 bag play)."
PACING = 'Pacing'


BagArgument = Annotated[
    Path, typer.Argument(exists=True, help='rosbag2 directory (mcap or sqlite3)')
]
RateOption = Annotated[
    float,
    typer.Option(
        '-r', '--rate', help='speed factor of the recorded rate (<= 0: as fast as possible)'
    ),
]
TopicsOption = Annotated[
    list[str] | None,
    typer.Option(help='only these topics (repeatable; --topics A B also works)'),
]
ClockOption = Annotated[bool, typer.Option('--clock', help='publish /clock with the bag time')]
ClockRateOption = Annotated[float, typer.Option(min=0.1, help='/clock frequency, Hz')]
LoopOption = Annotated[bool, typer.Option('-l', '--loop', help='play again and again')]
DelayOption = Annotated[
    float,
    typer.Option('-d', '--delay', min=0.0, help='seconds to wait before the first message'),
]
WaitForSubscribersOption = Annotated[
    int,
    typer.Option(
        metavar='N',
        min=0,
        help='hold playback until the waited topics (--wait-topic; default: the clouds) '
        'have N subscribers, and every other topic someone subscribes is matched',
    ),
]
WaitTimeoutOption = Annotated[float, typer.Option(min=0.0, help='seconds to wait for subscribers')]
WaitTopicOption = Annotated[
    list[str] | None,
    typer.Option(
        help='a topic --wait-for-subscribers waits for (repeatable; default: the '
        "bag's PointCloud2 topics, or every topic without clouds)"
    ),
]
QosDepthOption = Annotated[
    int, typer.Option(min=1, help='history depth of the (reliable) publishers')
]
PaceTopicOption = Annotated[
    str | None,
    typer.Option(
        help='after each PointCloud2 message, wait for one message on this topic (e.g. '
        '/diagnostics of a slow consumer) so none is dropped',
        rich_help_panel=PACING,
    ),
]
PaceTypeOption = Annotated[
    str, typer.Option(help='message type of --pace-topic', rich_help_panel=PACING)
]
PaceTimeoutOption = Annotated[
    float,
    typer.Option(
        min=0.0, help='seconds to wait for each answer on --pace-topic', rich_help_panel=PACING
    ),
]
QuietOption = Annotated[bool, typer.Option('--quiet', help='no log output')]


def play(
    context: typer.Context,
    bag: BagArgument,
    rate: RateOption = 1.0,
    topics: TopicsOption = None,
    clock: ClockOption = False,
    clock_rate: ClockRateOption = 100.0,
    loop: LoopOption = False,
    delay: DelayOption = 0.0,
    wait_for_subscribers: WaitForSubscribersOption = 0,
    wait_timeout: WaitTimeoutOption = 30.0,
    wait_topic: WaitTopicOption = None,
    qos_depth: QosDepthOption = 1000,
    pace_topic: PaceTopicOption = None,
    pace_type: PaceTypeOption = 'diagnostic_msgs/msg/DiagnosticArray',
    pace_timeout: PaceTimeoutOption = 60.0,
    quiet: QuietOption = False,
) -> int:
    """Publish a bag's topics at the recorded rate (alias mlsemreg-play)."""
    from mlsemreg_ros.ros.play_bag import play_bag
    from mlsemreg_ros.ros.player import PlayOptions

    return play_bag(bag, options_from(context, PlayOptions, wait_topics=wait_topic))


def expand_topics(argv: list[str]) -> list[str]:
    """``--topics A B`` (one flag, several values, as before) -> ``--topics A --topics B``."""
    out, in_topics = [], False
    for item in argv:
        if item == '--topics':
            in_topics = True
            continue
        if in_topics and not item.startswith('-'):
            out += ['--topics', item]
            continue
        in_topics = False
        out.append(item)
    return out


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``mlsemreg-play`` alias (same flags as the subcommand)."""
    return run(
        single_command_app(play, HELP),
        expand_topics(list(argv) if argv is not None else sys.argv[1:]),
        'mlsemreg-play',
    )


if __name__ == '__main__':
    sys.exit(main())

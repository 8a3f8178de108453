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
``mlsemreg demo``: the real node on a simulated drive, scored like ``mlsemreg eval-bag``.

The run (simulate into a cache, start ``mlsemreg_node``, play the bag paced by the node,
record and score it, write the results folder) is
:func:`mlsemreg_ros.ros.demo_run.run_demo`; this module is its command line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from mlsemreg_ros.tools.common import (
    alias,
    ConfigOption,
    options_from,
    OUTPUT,
    QuietOption,
    SetOption,
    settings,
)
import typer

HELP = (
    'Simulate a drive (cached), run mlsemreg_node on it through the player, record its '
    'odometry, print the metrics and write plots.'
)

FramesOption = Annotated[int, typer.Option(min=2, help='scans of the simulated drive')]
SeedOption = Annotated[int, typer.Option(min=0, help='world seed')]
CacheDirOption = Annotated[Path, typer.Option(help='where simulated bags are kept')]
OutputOption = Annotated[
    Path | None,
    typer.Option(
        '-o',
        '--output',
        help='results folder (default: results/demo/<time>_<bag>, link results/demo/latest)',
        rich_help_panel=OUTPUT,
    ),
]
RateOption = Annotated[
    float, typer.Option(help='player speed factor (playback is also paced by the node)')
]
DomainIdOption = Annotated[
    int,
    typer.Option(
        min=0, max=232, envvar='ROS_DOMAIN_ID', help='ROS_DOMAIN_ID of the node and the player'
    ),
]
TimeoutOption = Annotated[
    float, typer.Option(min=1.0, help='seconds to wait for the node on one scan')
]


def demo(
    context: typer.Context,
    frames: FramesOption = 100,
    seed: SeedOption = 0,
    cache_dir: CacheDirOption = Path('.cache'),
    output: OutputOption = None,
    rate: RateOption = 1.0,
    domain_id: DomainIdOption = 0,
    timeout: TimeoutOption = 120.0,
    config: ConfigOption = None,
    overrides: SetOption = None,
    quiet: QuietOption = False,
) -> int:
    """Run mlsemreg_node on a simulated drive and score it (alias mlsemreg-demo)."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.evaluation import tables
    from mlsemreg_ros.evaluation.settings import EvaluationSettings
    from mlsemreg_ros.ros.demo_run import DemoOptions, run_demo
    from mlsemreg_ros.ros.node_config import NodeConfig

    core, node_settings, evaluation = settings(
        (RegistrationConfig, NodeConfig, EvaluationSettings), config, overrides
    )
    options = options_from(context, DemoOptions)
    result = run_demo(options, core, node_settings, evaluation.evaluation, list(overrides or []))
    tables.print_table(tables.sequence_summary_table(result.summary, result.method))
    tables.print_text(f'results: {result.out}  ({result.seconds:.0f} s in total)')
    return 0 if result.complete else 1


main = alias(demo, HELP, 'mlsemreg-demo')

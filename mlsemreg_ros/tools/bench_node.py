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
``mlsemreg bench-node``: per-frame latency of mlsemreg_node (default parameters unless set).

The run (the node in-process, a probe node publishing pairs at a steady rate) is
:func:`mlsemreg_ros.ros.node_bench.measure_node_latency`; the measurement is
:mod:`mlsemreg_ros.evaluation.node_latency`. This module is its command line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from mlsemreg_ros.tools.common import (
    alias,
    ConfigOption,
    DATA,
    options_from,
    OUTPUT,
    SetOption,
    settings,
)
import typer

HELP = 'Per-frame latency of mlsemreg_node, driven by a probe node over DDS.'


PairsDirOption = Annotated[
    Path | None,
    typer.Option(
        '--pairs',
        file_okay=False,
        help='directory of pair files (default: the KITTI dev '
        'pairs; the synthetic street when absent)',
        rich_help_panel=DATA,
    ),
]
SyntheticOption = Annotated[
    bool, typer.Option('--synthetic', help='use the synthetic street', rich_help_panel=DATA)
]
LimitOption = Annotated[int, typer.Option(min=1, help='pairs to use', rich_help_panel=DATA)]
RepeatsOption = Annotated[int, typer.Option(min=1, help='registrations per pair and direction')]
RateOption = Annotated[float, typer.Option(min=0.01, help='publish rate, Hz')]
DomainIdOption = Annotated[
    int | None, typer.Option(min=0, max=232, help='ROS domain id (default: ROS_DOMAIN_ID)')
]
JsonPathOption = Annotated[
    Path | None,
    typer.Option(
        '--json', dir_okay=False, help='write records + summary here', rich_help_panel=OUTPUT
    ),
]


def bench_node(
    context: typer.Context,
    pairs_dir: PairsDirOption = None,
    synthetic: SyntheticOption = False,
    limit: LimitOption = 10,
    repeats: RepeatsOption = 2,
    rate: RateOption = 2.0,
    domain_id: DomainIdOption = None,
    json_path: JsonPathOption = None,
    config: ConfigOption = None,
    overrides: SetOption = None,
) -> int:
    """Per-frame latency of mlsemreg_node (alias mlsemreg-bench-node)."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.evaluation import tables
    from mlsemreg_ros.evaluation.node_latency import latency_table
    from mlsemreg_ros.evaluation.reports import write_json
    from mlsemreg_ros.evaluation.settings import EvaluationSettings
    from mlsemreg_ros.ros.node_bench import measure_node_latency, NodeBenchOptions
    from mlsemreg_ros.ros.node_config import NodeConfig

    core, node, evaluation = settings(
        (RegistrationConfig, NodeConfig, EvaluationSettings), config, overrides
    )
    options = options_from(context, NodeBenchOptions)
    bounds = evaluation.evaluation
    report = measure_node_latency(
        options, core, node, bounds, list(overrides or []), config is not None
    )
    tables.print_table(latency_table(report['summary'], bounds))
    if json_path:
        write_json(json_path, report)
        tables.print_text(f'wrote {json_path}')
    return 0


main = alias(bench_node, HELP, 'mlsemreg-bench-node')

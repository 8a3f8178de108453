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

Runs the node in-process (its own rclpy context and executor thread) and a probe node
(:mod:`mlsemreg_ros.ros.probe`) that publishes the dev pairs (or the synthetic street when
they are absent) on ``points`` at a steady rate; the measurement is
:mod:`mlsemreg_ros.evaluation.node_latency`.
"""

from __future__ import annotations

from pathlib import Path
import tempfile
from typing import Annotated, Any

from mlsemreg_ros.tools.common import (
    alias,
    ConfigOption,
    DATA,
    OUTPUT,
    SetOption,
    settings,
)
import typer

HELP = 'Per-frame latency of mlsemreg_node, driven by a probe node over DDS.'


def load_pairs(directory: Path | None, limit: int) -> list[Any]:
    """Up to ``limit`` pairs from ``directory``; the synthetic street if it holds none."""
    from mlsemreg_ros.datasets.pairs import list_pairs, load_pair
    from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair

    if directory is not None and directory.is_dir() and list_pairs(directory):
        return [load_pair(p) for p in list_pairs(directory)[:limit]]
    return [synthetic_pair(seed) for seed in range(limit)]


def bench_node(
    pairs_dir: Annotated[
        Path | None,
        typer.Option(
            '--pairs',
            file_okay=False,
            help='directory of pair files (default: the KITTI dev '
            'pairs; the synthetic street when absent)',
            rich_help_panel=DATA,
        ),
    ] = None,
    synthetic: Annotated[
        bool, typer.Option('--synthetic', help='use the synthetic street', rich_help_panel=DATA)
    ] = False,
    limit: Annotated[int, typer.Option(min=1, help='pairs to use', rich_help_panel=DATA)] = 10,
    repeats: Annotated[int, typer.Option(min=1, help='registrations per pair and direction')] = 2,
    rate: Annotated[float, typer.Option(min=0.01, help='publish rate, Hz')] = 2.0,
    domain_id: Annotated[
        int | None, typer.Option(min=0, max=232, help='ROS domain id (default: ROS_DOMAIN_ID)')
    ] = None,
    json_path: Annotated[
        Path | None,
        typer.Option(
            '--json', dir_okay=False, help='write records + summary here', rich_help_panel=OUTPUT
        ),
    ] = None,
    config: ConfigOption = None,
    overrides: SetOption = None,
) -> int:
    """Per-frame latency of mlsemreg_node (alias mlsemreg-bench-node)."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.datasets.pairs import dev_pairs_dir
    from mlsemreg_ros.evaluation import tables
    from mlsemreg_ros.evaluation.node_latency import (
        bench_node_latency,
        latency_summary,
        latency_table,
    )
    from mlsemreg_ros.evaluation.reports import write_json
    from mlsemreg_ros.evaluation.settings import EvaluationSettings
    from mlsemreg_ros.ros.node_config import NodeConfig
    from mlsemreg_ros.ros.node_process import write_params_file
    from mlsemreg_ros.ros.probe import node_and_probe

    core, node, evaluation = settings(
        (RegistrationConfig, NodeConfig, EvaluationSettings), config, overrides
    )
    directory = None if synthetic else (pairs_dir or dev_pairs_dir())
    pairs = load_pairs(directory, limit)
    tables.print_text(
        f'{len(pairs)} pair(s) from '
        f'{directory if directory else "the synthetic street"}; {repeats} x 2 '
        f'registrations each at {rate:g} Hz'
    )
    if overrides:
        tables.print_text('parameters: ' + ', '.join(overrides))
    with tempfile.TemporaryDirectory() as folder:
        ros_args = None
        if config is not None or overrides:
            params = write_params_file(Path(folder) / 'params.yaml', core, node)
            ros_args = ['--ros-args', '--params-file', str(params)]
        with node_and_probe(domain_id, ros_args) as (_, probe):
            records = bench_node_latency(pairs, repeats, rate, probe, evaluation.evaluation)
    result = latency_summary(records)
    tables.print_table(latency_table(result, evaluation.evaluation))
    if json_path:
        write_json(json_path, {'summary': result, 'records': records})
        tables.print_text(f'wrote {json_path}')
    return 0


main = alias(bench_node, HELP, 'mlsemreg-bench-node')

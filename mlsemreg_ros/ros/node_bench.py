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
``mlsemreg bench-node``'s run: mlsemreg_node's per-frame latency, driven by a probe node.

:func:`measure_node_latency` runs the node in-process (its own rclpy context and
executor thread) and a probe node (:mod:`mlsemreg_ros.ros.probe`) that publishes the dev
pairs (or the synthetic street when they are absent) on ``points`` at a steady rate; the
measurement and its summary are :mod:`mlsemreg_ros.evaluation.node_latency`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import tempfile
from typing import Any


@dataclass(frozen=True)
class NodeBenchOptions:
    """Which pairs, how often, at what rate, on which domain."""

    pairs_dir: Path | None = None  # pair files (None: the KITTI dev pairs, else synthetic)
    synthetic: bool = False  # the synthetic street even when pairs are present
    limit: int = 10  # pairs to use
    repeats: int = 2  # registrations per pair and direction
    rate: float = 2.0  # publish rate, Hz
    domain_id: int | None = None  # ROS domain id (None: ROS_DOMAIN_ID)


def load_pairs(directory: Path | None, limit: int) -> list[Any]:
    """Up to ``limit`` pairs from ``directory``; the synthetic street if it holds none."""
    from mlsemreg_ros.datasets.pairs import list_pairs, load_pair
    from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair

    if directory is not None and directory.is_dir() and list_pairs(directory):
        return [load_pair(p) for p in list_pairs(directory)[:limit]]
    return [synthetic_pair(seed) for seed in range(limit)]


def measure_node_latency(
    options: NodeBenchOptions,
    core: Any,
    node: Any,
    bounds: Any,
    overrides: list[str],
    config_given: bool = False,
) -> dict[str, Any]:
    """
    Measure the node; return ``{'summary': ..., 'records': [...]}`` (the ``--json``).

    The node runs with the settings ``core`` and ``node`` as its parameter file when
    ``config_given`` or ``overrides`` (else its defaults); prints what it measures.
    """
    from mlsemreg_ros.datasets.pairs import dev_pairs_dir
    from mlsemreg_ros.evaluation import tables
    from mlsemreg_ros.evaluation.node_latency import bench_node_latency, latency_summary
    from mlsemreg_ros.ros.node_process import write_params_file
    from mlsemreg_ros.ros.probe import node_and_probe

    directory = None if options.synthetic else (options.pairs_dir or dev_pairs_dir())
    pairs = load_pairs(directory, options.limit)
    tables.print_text(
        f'{len(pairs)} pair(s) from '
        f'{directory if directory else "the synthetic street"}; {options.repeats} x 2 '
        f'registrations each at {options.rate:g} Hz'
    )
    if overrides:
        tables.print_text('parameters: ' + ', '.join(overrides))
    with tempfile.TemporaryDirectory() as folder:
        ros_args = None
        if config_given or overrides:
            params = write_params_file(Path(folder) / 'params.yaml', core, node)
            ros_args = ['--ros-args', '--params-file', str(params)]
        with node_and_probe(options.domain_id, ros_args) as (_, probe):
            records = bench_node_latency(pairs, options.repeats, options.rate, probe, bounds)
    return {'summary': latency_summary(records), 'records': records}

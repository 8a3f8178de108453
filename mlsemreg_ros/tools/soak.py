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

"""``mlsemreg soak BAG``: thousands of scans through the node; its memory over time."""

from __future__ import annotations

from pathlib import Path
import tempfile
from typing import Annotated

from mlsemreg_ros.tools.common import alias, CommandError
import typer

HELP = (
    'Publish the scans of a bag in a loop to mlsemreg_node (its own process, default '
    'parameters) and sample its resident memory: the growth after the warm-up.'
)


def soak(
    bag: Annotated[Path, typer.Argument(help='bag with labeled clouds', exists=True)],
    frames: Annotated[int, typer.Option(min=1, help='scans to publish')] = 2000,
    every: Annotated[int, typer.Option(min=1, help='scans between two samples')] = 100,
    warm_up: Annotated[
        int,
        typer.Option(
            min=0,
            help='scans before the growth is counted (the heap first grows to its working set)',
        ),
    ] = 500,
    domain_id: Annotated[int, typer.Option(min=0, max=232, help='ROS domain id')] = 77,
) -> int:
    """Soak the node with a looping bag (alias mlsemreg-soak)."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.datasets.factory import open_scan_source
    from mlsemreg_ros.evaluation.soak import growth_mb
    from mlsemreg_ros.evaluation.soak import soak as run_soak
    from mlsemreg_ros.evaluation.tables import print_table, print_text, ResultTable
    from mlsemreg_ros.ros.node_config import NodeConfig
    from mlsemreg_ros.ros.node_process import start_node, stop_node, write_params_file
    from mlsemreg_ros.ros.probe import probe_only
    import numpy as np

    source = open_scan_source(bag)
    try:
        scans = [
            (s.xyz, (s.labels if s.labels is not None else np.zeros(len(s))).astype(np.uint32))
            for s in source.scans()
        ]
    finally:
        source.close()
    with tempfile.TemporaryDirectory() as folder:
        params = write_params_file(
            Path(folder) / 'params.yaml',
            RegistrationConfig(),
            NodeConfig().replace({'qos.reliability': 'reliable'}),
        )
        node = start_node(domain_id, params, Path(folder) / 'node.log')
        try:
            with probe_only(domain_id) as probe:
                samples = run_soak(scans, frames, every, probe, node.pid)
        except RuntimeError as error:
            raise CommandError(str(error)) from None
        finally:
            stop_node(node)
    rows = [[str(s.frames), f'{s.rss_mb:.1f}', f'{s.seconds:.0f}'] for s in samples]
    print_table(ResultTable(('scans', 'RSS MiB', 's'), rows))
    after = [s.rss_mb for s in samples if s.frames >= warm_up]
    print_text(
        f'RSS growth after {warm_up} scans (least-squares trend): '
        f'{growth_mb(samples, warm_up):+.1f} MiB; range after the warm-up '
        f'{min(after):.1f}-{max(after):.1f} MiB ({frames} scans of {bag.name}, '
        f'{len(scans)} per loop)'
    )
    return 0


main = alias(soak, HELP, 'mlsemreg-soak')

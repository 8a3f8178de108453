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
``mlsemreg fuzz-node``: hostile IMU, wheel and time-field input through the real node.

The node runs in its own process with ``imu_topic`` and ``wheel_odometry_topic`` set; the
cases are ``evaluation/hostile_cases.py``, the run
:func:`mlsemreg_ros.evaluation.hostile_fuzz.fuzz_node_priors`; this module is its command
line. It prints the table by case and the totals (crashes, wrong poses published, clouds
answered, good scans published and right); ``-o DIR`` also writes ``cases.json``.
"""

from __future__ import annotations

from pathlib import Path
import tempfile
from typing import Annotated

from mlsemreg_ros.tools.common import alias, CommandError
import typer

HELP = (
    'Hostile IMU, wheel-odometry and per-point time input through mlsemreg_node (its own '
    'process, IMU and wheel topics set), each case followed by good scans: crashes, wrong '
    'poses, clouds answered, good scans published and right.'
)


PairsOption = Annotated[
    Path | None,
    typer.Option(
        help='folder of pair files (.npz, e.g. the KITTI dev pairs); default: the synthetic street'
    ),
]
RepeatOption = Annotated[
    int, typer.Option(min=1, help='runs of every case, each on the next pair')
]
OnlyOption = Annotated[str, typer.Option(help='run the cases whose name contains this')]
KeypointsOption = Annotated[int, typer.Option(min=100, help='keypoints.count of the node')]
SeedOption = Annotated[int, typer.Option(help='seed of the random hostile values')]
OutputOption = Annotated[Path | None, typer.Option('-o', '--output', help='write cases.json here')]
DomainIdOption = Annotated[int, typer.Option(min=0, max=232, help='ROS domain id')]


def fuzz_node(
    pairs: PairsOption = None,
    repeat: RepeatOption = 1,
    only: OnlyOption = '',
    keypoints: KeypointsOption = 1500,
    seed: SeedOption = 34,
    output: OutputOption = None,
    domain_id: DomainIdOption = 78,
) -> int:
    """Run the hostile cases through the node (alias mlsemreg-fuzz-node)."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.evaluation import hostile_fuzz as fuzz
    from mlsemreg_ros.evaluation.tables import print_table, print_text
    from mlsemreg_ros.ros.node_config import NodeConfig
    from mlsemreg_ros.ros.node_process import NodeProcess, write_params_file
    from mlsemreg_ros.ros.probe import probe_only

    try:
        scans = fuzz.fuzz_pairs(pairs)
    except fuzz.FuzzInputError as error:
        raise CommandError(str(error)) from None
    core = RegistrationConfig().replace({'keypoints.count': keypoints})
    node_cfg = NodeConfig().replace(
        {
            'qos.reliability': 'reliable',
            'imu_topic': fuzz.IMU_TOPIC,
            'wheel_odometry_topic': fuzz.WHEEL_TOPIC,
        }
    )
    with tempfile.TemporaryDirectory() as folder:
        params = write_params_file(Path(folder) / 'params.yaml', core, node_cfg)
        node = NodeProcess(domain_id, params, Path(folder) / 'node.log')
        try:
            with probe_only(domain_id) as probe:
                report = fuzz.fuzz_node_priors(
                    scans, probe, node, fuzz.FuzzOptions(repeat, only, seed)
                )
        except RuntimeError as error:
            raise CommandError(str(error)) from None
        finally:
            node.stop()
    print_table(report.table())
    print_text(report.summary())
    if output is not None:
        report.write(output)
    return 0 if report.passed else 1


main = alias(fuzz_node, HELP, 'mlsemreg-fuzz-node')

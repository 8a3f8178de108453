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
cases are ``evaluation/hostile_cases.py``, the runner ``evaluation/hostile_run.py``.
Prints the table by case and the totals (crashes, wrong poses published, clouds
answered, good scans published and right); ``-o DIR`` also writes ``cases.json``.
"""

from __future__ import annotations

from dataclasses import asdict
import json
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


def fuzz_node(
    pairs: Annotated[
        Path | None,
        typer.Option(
            help='folder of pair files (.npz, e.g. the KITTI dev pairs); default: '
            'the synthetic street'
        ),
    ] = None,
    repeat: Annotated[
        int, typer.Option(min=1, help='runs of every case, each on the next pair')
    ] = 1,
    only: Annotated[str, typer.Option(help='run the cases whose name contains this')] = '',
    keypoints: Annotated[int, typer.Option(min=100, help='keypoints.count of the node')] = 1500,
    seed: Annotated[int, typer.Option(help='seed of the random hostile values')] = 34,
    output: Annotated[
        Path | None, typer.Option('-o', '--output', help='write cases.json here')
    ] = None,
    domain_id: Annotated[int, typer.Option(min=0, max=232, help='ROS domain id')] = 78,
) -> int:
    """Run the hostile cases through the node (alias mlsemreg-fuzz-node)."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.evaluation.hostile_cases import cases, Timeline
    from mlsemreg_ros.evaluation.hostile_run import PriorPublisher, run_case
    from mlsemreg_ros.evaluation.tables import print_table, print_text, ResultTable
    from mlsemreg_ros.ros.node_config import NodeConfig
    from mlsemreg_ros.ros.node_process import start_node, stop_node, write_params_file
    from mlsemreg_ros.ros.probe import probe_only
    import numpy as np

    loaded, interval = _pairs(pairs)
    rng = np.random.default_rng(seed)
    core = RegistrationConfig().replace({'keypoints.count': keypoints})
    node_cfg = NodeConfig().replace(
        {
            'qos.reliability': 'reliable',
            'imu_topic': 'imu/data',
            'wheel_odometry_topic': 'wheel/odometry',
        }
    )
    results, crashes = [], 0
    with tempfile.TemporaryDirectory() as folder:
        params = write_params_file(Path(folder) / 'params.yaml', core, node_cfg)
        log = Path(folder) / 'node.log'
        node = start_node(domain_id, params, log)
        try:
            with probe_only(domain_id) as probe:
                priors = PriorPublisher(probe.node, 'imu/data', 'wheel/odometry')
                if not probe.wait_until(priors.connected, 60.0):
                    raise CommandError('the node did not subscribe to the prior topics')
                before: dict[str, int] = {}
                t0 = 1000.0
                count = len(cases(Timeline(t0, interval), rng))
                for run in range(repeat):
                    for k in range(count):
                        timeline = Timeline(t0, interval)
                        case = cases(timeline, rng)[k]  # its messages at this case's times
                        if only and only not in case.name:
                            continue
                        pair = loaded[(run * 7 + k) % len(loaded)]
                        result, before = run_case(
                            case,
                            pair,
                            timeline,
                            probe,
                            priors,
                            lambda process=node: process.poll() is None,
                            before,
                            rng,
                            keyframe_twice=pairs is None,
                        )
                        results.append(result)
                        t0 += 4 * interval + 1.0
                        if result.crashed:
                            crashes += 1
                            node = start_node(domain_id, params, log)
                            before = {}
                            probe.wait_until(priors.connected, 60.0)
        except RuntimeError as error:
            raise CommandError(str(error)) from None
        finally:
            stop_node(node)
    rows = [
        [
            r.group,
            r.name,
            f'{r.answered}/{r.clouds}',
            f'{r.good_right}/{r.good}',
            str(r.wrong),
            'yes' if r.crashed else '',
            ', '.join(
                f'{k}={v}'
                for k, v in sorted(r.counts.items())
                if '.' in k or k in ('prior_refused', 'deskew_refused')
            )[:120],
        ]
        for r in results
    ]
    print_table(
        ResultTable(('group', 'case', 'answered', 'good right', 'wrong', 'crash', 'counted'), rows)
    )
    good = sum(r.good for r in results)
    right = sum(r.good_right for r in results)
    clouds = sum(r.clouds for r in results)
    answered = sum(r.answered for r in results)
    wrong = sum(r.wrong for r in results)
    print_text(
        f'{len(results)} cases: {crashes} crashes, {wrong} wrong poses published, '
        f'{answered}/{clouds} clouds answered, {right}/{good} good scans after hostile input '
        f'published and right ({100.0 * right / max(good, 1):.1f} %)'
    )
    if output is not None:
        output.mkdir(parents=True, exist_ok=True)
        (output / 'cases.json').write_text(json.dumps([asdict(r) for r in results], indent=1))
    return 0 if crashes == 0 and wrong == 0 and answered == clouds else 1


def _pairs(folder: Path | None) -> tuple[list, float]:
    """
    Return the pairs and the interval (s) between the scans of the moved step.

    Pair files are sent as keyframe and moved scan only (``run_case``'s ``keyframe_twice``).
    """
    if folder is None:
        from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair

        return [synthetic_pair(seed=s) for s in range(3)], 0.1
    from mlsemreg_ros.datasets.pairs import list_pairs, load_pair

    files = list_pairs(folder)
    if not files:
        raise CommandError(f'no pair files in {folder}')
    return [load_pair(f) for f in files], 1.0  # ~20 m apart: 20 m/s, within the wheel limit


main = alias(fuzz_node, HELP, 'mlsemreg-fuzz-node')

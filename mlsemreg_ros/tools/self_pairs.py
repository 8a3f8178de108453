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
``mlsemreg self-pairs SCAN...``: real scans registered against moved copies of themselves.

Each PCD/PLY scan starts a fresh odometry with the given parameters; a copy moved by 2 m and
10 deg, then by 8 m and 30 deg, resampled to 70 % with 2 cm of noise, is registered onto it
(evaluation/self_pairs.py, docs/sensors.md). Prints the outcome and the parameters the
odometry picked for the sensor.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from mlsemreg_ros.tools.common import alias, CommandError, ConfigOption, SetOption, settings
import typer

HELP = (
    'Register real PCD/PLY scans against moved (2 m / 10 deg, 8 m / 30 deg), resampled, '
    'noisy copies of themselves through the odometry; print the outcome and the parameters '
    'picked for each sensor.'
)


def self_pairs(
    scans: Annotated[list[Path], typer.Argument(help='PCD/PLY files')],
    config: ConfigOption = None,
    overrides: SetOption = None,
) -> int:
    """Register each scan against its moved copies (alias mlsemreg-self-pairs)."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.maps.cloud_files import CloudFileError, read_cloud
    from mlsemreg_ros.evaluation.self_pairs import MOTIONS, register_self

    (core,) = settings((RegistrationConfig,), config, overrides)
    wrong = 0
    for path in scans:
        try:
            points = read_cloud(path).points
        except CloudFileError as error:
            raise CommandError(str(error)) from error
        for shift, yaw in MOTIONS:
            r = register_self(path.stem, points, core, shift, yaw)
            verdict = 'right' if r.right else ('WRONG' if r.accepted else 'refused')
            wrong += int(r.accepted and not r.right)
            print(
                f'{r.name:16s} {shift:4.1f} m {yaw:4.0f} deg: {verdict:7s} '
                f'RE {r.rotation_error_deg:6.2f} deg TE {r.translation_error_m:6.3f} m '
                f'{r.source:18s} {r.latency_ms:6.0f} ms | {r.picked}'
                + (f' | {r.reason}' if not r.right else '')
            )
    return 1 if wrong else 0


main = alias(self_pairs, HELP, 'mlsemreg-self-pairs')
